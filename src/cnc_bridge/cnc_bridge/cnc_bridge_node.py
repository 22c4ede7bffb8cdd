"""The ``cnc_bridge`` node: predicted errors -> bounded, rate-limited offsets on the machine.

A managed (lifecycle) node, thin ROS shell around :mod:`error_transform`,
:mod:`safety_envelope`, :mod:`audit_log` and an :mod:`offset_backend` (``twin`` or ``opcua``).
Run: ``python -m cnc_bridge.cnc_bridge_node`` (then ``configure`` and ``activate``; the
launcher drives them, ``autostart:=true`` does it without a manager).

* **configure** connects (opcua: within ``connect_timeout_s``, the server's certificate
  checked against the trust list; the client's event loop runs in the node's own thread,
  each write to completion, and a wall-clock timer serves it between writes), reads what
  the CNC holds and adopts it into the envelope only within its limits (clamped; 0 where compensation was off), one audit line per axis
  saying what was held and what was adopted. Configure never writes; a failed configure
  releases the connection and leaves the node unconfigured.
* **activate** starts writing: every prediction is transformed at the current positions,
  one envelope step at the prediction's stamp, write + read-back, one audit line per axis,
  ``offsets`` (AxisOffsets) published with the prediction's stamp, then, with ``lockstep``,
  SimSync ``processed_until`` = that stamp. Between predictions the envelope keeps stepping
  (timer, or machine_state instants in lock-step once the watchdog is due).
* **deactivate** switches compensation off: the offsets ramp to zero at
  ``disable_ramp_um_per_s`` (the envelope keeps stepping and writing only that ramp until
  every axis is at zero), predictions are no longer followed. A wall-clock bridge steps the
  ramp inside the transition, for at most ``deactivate_wait_s``, so that a clean stop leaves
  the CNC at zero when the ramp fits; in lock-step / simulated time the ramp follows the
  simulation's instants.
* **cleanup / shutdown** release the connection without writing: the CNC keeps what it was
  last told (no jump); the audit says what it holds.
* Parameters: the envelope's limits and ``enable`` apply at run time (validated, audited,
  in effect from the next step); every other parameter is read-only
  (:mod:`cnc_bridge.bridge_params`). Credentials come from :mod:`cnc_bridge.credentials`;
  a password, user or private key given as a parameter is refused.
While unconfigured the node does not subscribe; while inactive it still answers the
lock-step (SimSync) so that a simulation is never held by a bridge that was switched off.
Bad predictions (missing component, wrong unit, NaN) are logged naming the component and
skipped; nothing already applied changes, and the watchdog takes over if they persist.
"""
from __future__ import annotations

import gc
import math
import time

from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.timer import Timer
from std_msgs.msg import Header

from thermal_comp_common.node_runtime import (EVENT_QOS, SENSOR_QOS, TOPIC_ERRORS_PREDICTED,
                                       TOPIC_MACHINE_STATE, TOPIC_OFFSETS, TOPIC_SIM_SYNC,
                                       declare_parameters, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_msgs.msg import AxisOffsets, MachineState, SimSync, ThermalErrors

from cnc_bridge.audit_log import AuditLog
from cnc_bridge.bridge_params import (PARAMS, RUNTIME, changed_envelope, envelope_config,
                                      loosening)
from cnc_bridge.credentials import SECRET_NAMES, load_credentials
from cnc_bridge.error_transform import (ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS, HtmGeometry,
                                        LatheToolOffsets, TransformInputError, offsets_from_errors)
from cnc_bridge.offset_backend import TwinBackend, adopt_held_state
from cnc_bridge.safety_envelope import (LIMIT_WRITE_FAILED, EnvelopeConfigError, SafetyEnvelope,
                                        flag_names)
from cnc_bridge.update_profile import UpdateProfile

#: the launcher drives configure/activate/deactivate of a node module that says this
LIFECYCLE_NODE = True

SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
#: wall-clock period at which a backend whose I/O runs in the node's thread is served between
#: writes (OPC UA: health check, keep-alive, positions, reconnection), s
SERVE_PERIOD_S = 0.05


def _make_backend(p: dict):
    """The backend for parameters ``p``; opcua: connected within connect_timeout_s or raise."""
    if p["backend"] == "twin":
        return TwinBackend()
    from cnc_bridge.opcua_backend import OpcUaBackend
    from cnc_bridge.opcua_config import OpcUaConfig, default_node_map, load_node_map
    if p["node_map_file"]:
        node_map, scale = load_node_map(p["node_map_file"])
    else:
        axes = tuple(a for a in p["offset_axes"] if a)
        if p["compensation_mode"] == "kinematic" and axes == ("X", "Y", "Z"):
            axes = FIVE_AXIS_COMPONENTS   # one CNC parameter per location error
        node_map, scale = default_node_map(axes), 0.001
    creds = load_credentials(p["credentials_file"] or None)
    backend = OpcUaBackend(OpcUaConfig(
        endpoint=p["endpoint"], node_map=node_map, offset_units_per_um=scale,
        user=creds.user, password=creds.password,
        certificate=p["certificate"] or None, private_key=creds.private_key,
        server_certificate=p["server_certificate"] or None,
        server_trust=(p["server_trust"],) if p["server_trust"] else (),
        security_required=p["security_required"], timeout_s=p["request_timeout_s"]),
        inline=True)      # the client's loop runs in the node's thread: no hop per write
    if not backend.wait_connected(p["connect_timeout_s"]):
        error = backend.last_error or "no answer"
        backend.close()
        raise ConnectionError(f"not connected to {p['endpoint']} within "
                              f"{p['connect_timeout_s']} s: {error}")
    return backend


class CncBridgeNode(LifecycleNode):
    def __init__(self, context=None):
        super().__init__("cnc_bridge", context=context)
        secrets = sorted(n for n in self._parameter_overrides if n in SECRET_NAMES)
        if secrets:
            raise ValueError(
                f"parameter '{secrets[0]}': credentials are never parameters (anyone on the ROS "
                f"domain can read them, ps shows the command line); use credentials_file "
                f"(mode 600) or the THERMAL_COMP_OPCUA_* environment")
        self._p = declare_parameters(self, PARAMS)
        self.kinematic = self._p["compensation_mode"] == "kinematic"
        envelope_config(self._p, self.kinematic)     # bad limits: fail at start, naming the field
        if len(self._p["htm_origin_mm"]) != 3 or len(self._p["b_pivot_xz_mm"]) != 2:
            raise ValueError(f"parameters 'htm_origin_mm' (3 values) / 'b_pivot_xz_mm' (2 values): "
                             f"got {list(self._p['htm_origin_mm'])} / {list(self._p['b_pivot_xz_mm'])}")
        self.htm = HtmGeometry(tuple(self._p["htm_origin_mm"]), tuple(self._p["b_pivot_xz_mm"]))
        self.envelope: SafetyEnvelope | None = None
        self.backend = None
        self.audit: AuditLog | None = None
        self.lathe = None
        self.adopted = []                 # HeldAdoption per axis from the last configure
        self._adoption_flags: dict[str, int] = {}
        self._active = False              # writes follow the predictions
        self._ramping_down = False        # deactivated, offsets still on their way to zero
        self._entities = []               # publishers, subscriptions, timer of a configured node
        self.offsets_pub = self.sync_pub = None
        #: timed only with profile_path: between predictions (no begin) its laps do nothing
        self.profile = UpdateProfile()
        self.add_on_set_parameters_callback(self._check_params)
        self.add_post_set_parameters_callback(self._on_params_set)
        if self._p["autostart"]:
            if self.trigger_configure() != SUCCESS:
                raise ValueError(f"autostart: configure failed ({self._configure_error})")
            if self.trigger_activate() != SUCCESS:
                raise ValueError("autostart: activate failed (see the log)")

    # ------------------------------------------------------------------ lifecycle
    _configure_error = ""

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        p = self._p
        try:
            self.envelope = SafetyEnvelope(envelope_config(p, self.kinematic), enabled=False)
            self.lathe = self._load_lathe(p["lathe_tools_file"])
            self.audit = AuditLog(p["audit_log_path"]) if p["audit_log_path"] else None
            self.backend = _make_backend(p)
        except (ValueError, OSError, ConnectionError) as exc:
            self._configure_error = str(exc)
            self.get_logger().error(f"configure failed, nothing written: {exc}")
            self._release()
            return FAILURE
        self.adopted = adopt_held_state(self.envelope, self.backend)
        # the first offsets message after activation carries what the adoption limited
        self._adoption_flags = {a.axis: a.flags for a in self.adopted if a.flags}
        for a in self.adopted:
            text = "start-up: " + a.describe()
            if a.flags:      # rclpy: one severity per call site
                self.get_logger().warning(text)
            else:
                self.get_logger().info(text)
            self._audit_event(a.axis, text, a.flags)
        self._positions: dict[str, float] = {}
        self._errors: dict[str, float] | None = None
        self._last_update_t: float | None = None
        self._warned_positions = False
        # subscriptions first: the lock-step counts a participant present once its SimSync
        # publisher appears, and the first prediction must then find the subscription
        self._entities = [self.create_subscription(MachineState, TOPIC_MACHINE_STATE, self._on_state,
                                                   SENSOR_QOS),
                          self.create_subscription(ThermalErrors, TOPIC_ERRORS_PREDICTED,
                                                   self._on_prediction, EVENT_QOS)]
        self.offsets_pub = self.create_publisher(AxisOffsets, TOPIC_OFFSETS, EVENT_QOS)
        self.sync_pub = (self.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
                         if p["lockstep"] else None)
        self._entities += [self.offsets_pub, self.sync_pub]
        if not p["lockstep"]:
            self._entities.append(self.create_timer(p["update_period_s"], self._on_timer))
        if hasattr(self.backend, "serve"):
            self._entities.append(self.create_timer(SERVE_PERIOD_S, self.backend.serve,
                                                    clock=Clock(clock_type=ClockType.STEADY_TIME)))
        self.get_logger().info(
            f"configured: backend {p['backend']}, limit {p['abs_limit_um']} um, rate "
            f"{p['max_rate_um_per_s']} um/s, watchdog {p['watchdog_timeout_s']} s; not writing "
            f"until activated")
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.envelope.set_enabled(bool(self.get_parameter("enable").value))
        self._active, self._ramping_down = True, False
        # what start-up allocated (modules, the client, the node) stays out of the garbage
        # collector's passes: a full collection over it is a pause on the offsets' path
        gc.freeze()
        self._audit_event("", f"activate: compensation {'enabled' if self.envelope.enabled else 'DISABLED'}")
        self.get_logger().info(f"active: writing offsets from "
                               f"{self._fmt(self.envelope.applied)} (rate-limited)")
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = False
        self.envelope.set_enabled(False)
        self._ramping_down = any(abs(v) > 0 for v in self.envelope.applied.values())
        text = (f"deactivate: compensation off, offsets ramp to zero at "
                f"{self.envelope.config.disable_ramp_um_per_s} um/s from {self._fmt(self.envelope.applied)}")
        self._audit_event("", text)
        self.get_logger().info(text)
        if self._ramping_down and not self._p["lockstep"] and \
                not self.get_parameter("use_sim_time").value:
            self._ramp_down_for(self._p["deactivate_wait_s"])
        return SUCCESS

    def _ramp_down_for(self, wait_s: float) -> None:
        """Step the ramp to zero in real time (the executor is ours meanwhile) until every
        offset is at zero or ``wait_s`` passed; the ramp goes on after that on the timer."""
        deadline = time.monotonic() + wait_s
        while self._ramping_down and time.monotonic() < deadline:
            # pacing a physical ramp in wall time: the rate limit is per second of real time
            time.sleep(min(self._p["update_period_s"], max(0.0, deadline - time.monotonic())))
            t = self.get_clock().now().nanoseconds * 1e-9
            self._update(t, s_to_stamp(t), fresh=False)
        if self._ramping_down:
            self.get_logger().warning(
                f"deactivate: not at zero after {wait_s:g} s ({self._fmt(self.envelope.applied)}); "
                f"the ramp goes on while the node runs, a stop now leaves these offsets held")

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release("cleanup")
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release("shutdown")
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release("error")
        return SUCCESS

    def _release(self, why: str = "") -> None:
        """Drop the connection and the ROS entities without writing (the CNC keeps its offsets)."""
        self._active = self._ramping_down = False
        if why and self.envelope is not None:
            held = self._fmt(self.envelope.applied)
            self._audit_event("", f"{why}: released without writing; the CNC keeps {held}")
            self.get_logger().info(f"{why}: the CNC keeps {held}")
        for e in self._entities:
            if isinstance(e, Timer):
                self.destroy_timer(e)
            elif isinstance(e, Publisher):
                self.destroy_publisher(e)
            elif isinstance(e, Subscription):
                self.destroy_subscription(e)
        self._entities, self.offsets_pub, self.sync_pub = [], None, None
        if self.backend is not None:
            self.backend.close()
            self.backend = None
        if self.audit is not None:
            self.audit.close()
            self.audit = None

    @staticmethod
    def _load_lathe(path: str):
        if not path:
            return None
        import yaml
        try:
            with open(path, encoding="utf-8") as f:
                return LatheToolOffsets.from_mapping(yaml.safe_load(f))
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise ValueError(f"parameter 'lathe_tools_file': {exc}") from exc

    @staticmethod
    def _fmt(values: dict[str, float]) -> str:
        return ", ".join(f"{a}={v:.3f} {'um/m' if a in ANGULAR_COMPONENTS else 'um'}"
                         for a, v in sorted(values.items())) or "nothing"

    def _audit_event(self, axis: str, text: str, flags: int = 0) -> None:
        if self.audit is not None:
            self.audit.log_event(self.get_clock().now().nanoseconds * 1e-9, axis, text, flags)

    # ------------------------------------------------------------------ parameters
    def _check_params(self, params: list[Parameter]) -> SetParametersResult:
        changes = {prm.name: prm.value for prm in params if prm.name in RUNTIME}
        why = loosening(changes, self._p) if self._active else None
        if why is not None:
            self.get_logger().warning(f"refused: {why}")
            return SetParametersResult(successful=False, reason=why)
        if self.envelope is not None and changes:
            try:
                changed_envelope(self.envelope.config, changes, self.kinematic)
            except (EnvelopeConfigError, TypeError, ValueError) as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _on_params_set(self, params: list[Parameter]) -> None:
        changes = {prm.name: prm.value for prm in params if prm.name in RUNTIME}
        for name, value in changes.items():
            old = self._p.get(name)
            self._p[name] = value
            text = f"parameter {name}: {old} -> {value} (applied from the next step)"
            self.get_logger().warning(text)
            self._audit_event("", text)
        if self.envelope is None:
            return               # unconfigured: configure reads the new values
        new = changed_envelope(self.envelope.config, changes, self.kinematic)
        if new is not None:
            self.envelope.reconfigure(new)
        if "enable" in changes and self._active:
            self.envelope.set_enabled(bool(changes["enable"]))

    # ------------------------------------------------------------------ inputs
    def _on_state(self, msg: MachineState) -> None:
        if len(msg.axis_names) != len(msg.axis_positions):
            self.get_logger().error(
                f"machine_state: {len(msg.axis_names)} axis_names but "
                f"{len(msg.axis_positions)} axis_positions; ignored")
            return
        self._positions = dict(zip(msg.axis_names, msg.axis_positions))
        t = stamp_to_s(msg.header.stamp)
        fresh_t = self.envelope.last_fresh_t
        if (self._writing and self._p["lockstep"] and fresh_t is not None
                and t - fresh_t > self._p["watchdog_timeout_s"]):
            self._update(t, msg.header.stamp, fresh=False)

    def _on_prediction(self, msg: ThermalErrors) -> None:
        t = stamp_to_s(msg.header.stamp)
        if self._p["profile_path"]:
            self.profile.begin(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        try:
            self._errors = self._errors_from(msg)
            fresh = True
        except ValueError as exc:
            # keep what is applied (the watchdog takes over if this persists), but still
            # answer t_k so that a lock-step simulation does not stall on a bad message
            self.get_logger().error(f"errors/predicted at t={t:.3f}: {exc}; prediction skipped")
            fresh = False
        if self._writing:
            self._update(t, msg.header.stamp, fresh=fresh)
        if self.sync_pub is not None:
            self.sync_pub.publish(SimSync(header=Header(stamp=msg.header.stamp),
                                          node_name=self.get_name(),
                                          processed_until=msg.header.stamp))
        self.profile.lap("ack")
        self.profile.end()

    @property
    def _writing(self) -> bool:
        """Active, or deactivated with offsets still ramping to zero."""
        return self._active or self._ramping_down

    def _on_timer(self) -> None:
        if not self._writing:
            return
        t = self.get_clock().now().nanoseconds * 1e-9
        if self._last_update_t is not None and t - self._last_update_t < self._p["update_period_s"]:
            return
        self._update(t, s_to_stamp(t), fresh=False)

    @staticmethod
    def _errors_from(msg: ThermalErrors) -> dict[str, float]:
        n = len(msg.component_names)
        if len(msg.values) != n or (len(msg.units) not in (0, n)):
            raise ValueError(f"{n} component_names but {len(msg.values)} values and "
                             f"{len(msg.units)} units")
        if msg.source != ThermalErrors.SOURCE_PREDICTED:
            raise ValueError(f"source {msg.source} is not SOURCE_PREDICTED")
        errors = {}
        for i, name in enumerate(msg.component_names):
            if msg.units:
                want = ThermalErrors.UNIT_UM_PER_M if name in ANGULAR_COMPONENTS else ThermalErrors.UNIT_UM
                if msg.units[i] != want:
                    raise ValueError(f"component '{name}' has unit {msg.units[i]}, expected {want} "
                                     f"({'um/m' if want else 'um'})")
            v = float(msg.values[i])
            if not math.isfinite(v):
                raise ValueError(f"component '{name}' is {v}")
            errors[name] = v
        return errors

    # ------------------------------------------------------------------ the update
    def _positions_now(self) -> dict[str, float]:
        pos = dict(self.backend.axis_positions())
        pos.update(self._positions)           # machine_state wins where it reports the axis
        if self._p["positions_required"] or self._errors is None or \
                not any(c in self._errors for c in FIVE_AXIS_COMPONENTS):
            return pos
        missing = [a for a in ("X", "Y", "Z") if a not in pos]
        if missing:
            origin = self.htm.origin_at_mm(pos.get("B", 0.0))
            for a in missing:
                pos[a] = float(origin["XYZ".index(a)])
            if not self._warned_positions:
                self._warned_positions = True
                self.get_logger().warning(
                    f"no position for axis {missing} from machine_state or the CNC: offsets are "
                    f"evaluated at the HTM origin {list(self.htm.origin_mm)} mm")
        return pos

    def _update(self, t: float, stamp, fresh: bool) -> None:
        commanded = None
        if self._errors is not None and self.kinematic:
            # the CNC's kinematic model takes the location errors themselves
            commanded = dict(self._errors)
        elif self._errors is not None:
            try:
                commanded = offsets_from_errors(self._errors, self._positions_now(),
                                                self._p["sphere_radius_mm"], self.lathe, self.htm,
                                                self._p["htm_convention"])
            except TransformInputError as exc:
                self.get_logger().error(f"offsets at t={t:.3f}: {exc}; holding", throttle_duration_sec=10.0)
                fresh = False
        prof = self.profile
        prof.lap("transform")
        try:
            decisions = self.envelope.step(t, commanded, fresh)
        except ValueError as exc:
            self.get_logger().error(f"offsets at t={t:.3f}: {exc}; holding")
            return
        prof.lap("envelope")
        self._last_update_t = t
        if not decisions:
            return
        try:
            readback = self.backend.write_offsets({d.axis: d.applied_um for d in decisions})
        except ValueError as exc:            # e.g. an axis without an offset node in the map
            self.get_logger().error(f"offsets at t={t:.3f} not written: {exc}",
                                    throttle_duration_sec=10.0)
            readback = {d.axis: None for d in decisions}
        prof.lap("cnc_call")
        prof.note(round_trip_ms=getattr(self.backend, "last_round_trip_s", 0.0) * 1e3,
                  round_trips=getattr(self.backend, "last_round_trips", 0))
        msg = AxisOffsets(header=Header(stamp=stamp), compensation_enabled=self.envelope.enabled)
        entries = []
        for d in decisions:
            back = readback.get(d.axis)
            self.envelope.confirm(d.axis, back)
            flags = d.flags | (LIMIT_WRITE_FAILED if back is None else 0) | \
                self._adoption_flags.pop(d.axis, 0)
            msg.axis_names.append(d.axis)
            msg.commanded_offsets_um.append(d.commanded_um)
            msg.applied_offsets_um.append(self.envelope.applied[d.axis])
            msg.applied.append(back is not None)
            msg.limits_hit.append(flags)
            entries.append((d.axis, d.commanded_um, back, flags))
            if flags & LIMIT_WRITE_FAILED:
                self.get_logger().warning(
                    f"axis {d.axis}: write of {d.applied_um:.3f} um not confirmed "
                    f"({getattr(self.backend, 'last_error', '')})", throttle_duration_sec=5.0)
        # what the CNC confirmed goes out first; the audit line is on disk before this returns,
        # so before the lock-step acknowledgement that lets the simulation go on
        self.offsets_pub.publish(msg)
        prof.lap("publish")
        if self.audit is not None:
            self.audit.log_write(t, entries)
        prof.lap("audit")
        if self._ramping_down and all(v == 0.0 for v in self.envelope.applied.values()):
            self._ramping_down = False
            self._audit_event("", "deactivated: every offset is at zero; writes stopped")
            self.get_logger().info("deactivated: every offset is at zero; writes stopped")
        self.get_logger().debug(" ".join(f"{e[0]}={e[2]} [{flag_names(e[3])}]" for e in entries))

    def close(self) -> None:
        """Process exit (run_node): release without writing, like shutdown."""
        self._release("exit" if self.backend is not None else "")
        if self._p["profile_path"]:
            self.profile.write_csv(self._p["profile_path"])


def main(args=None) -> int:
    return run_node(CncBridgeNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
