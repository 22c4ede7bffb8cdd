"""The ``cnc_bridge`` node: predicted errors -> bounded, rate-limited offsets on the machine.

A managed (lifecycle) node, thin ROS shell around :mod:`bridge_core` (the write path through
:mod:`error_transform`, :mod:`safety_envelope`, an :mod:`offset_backend`, ``twin`` or
``opcua``, and :mod:`audit_log`).
Run: ``python -m cnc_bridge.cnc_bridge_node`` (then ``configure`` and ``activate``; the
launcher drives them, ``autostart:=true`` does it without a manager).

* **configure** connects (opcua: within ``connect_timeout_s``, the server's certificate
  checked against the trust list; the client's event loop runs in the node's own thread,
  each write to completion, and a wall-clock timer serves it between writes), reads what
  the CNC holds and adopts it into the envelope only within its limits (0 where compensation
  was off; beyond the limit: not adopted, activation refused), one audit line per axis
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
* **diagnostics**: one status ``bridge`` on ``/diagnostics`` (1 Hz and on change) with the
  lifecycle state, the connection, its security and reconnections, the last confirmed write
  (stamp, host time, values), the counts of writes, clamps, rate-limited writes, refusals and
  failed writes, and the watchdog (:mod:`cnc_bridge.status`); the counters live in
  :class:`~cnc_bridge.bridge_core.BridgeCore`.
* **a reconnection** (a restarted CNC) is a start-up again: what the CNC holds now is adopted
  and ramped from, or, beyond the envelope with compensation on, the bridge stops writing with
  one error line until it is configured again (:meth:`BridgeCore.readopt_after_reconnect`).
* **activation is refused** (one error line, audited, the node stays inactive) while the CNC
  applied an offset beyond the envelope at configure: no write could bring it back within
  the rate limit. The operator brings the CNC's offset within the limit (or switches its
  compensation off) and configures again.
While unconfigured the node does not subscribe; while inactive it still answers the
lock-step (SimSync) so that a simulation is never held by a bridge that was switched off.
Bad predictions (missing component, wrong unit, NaN) are logged naming the component and
skipped; nothing already applied changes, and the watchdog takes over if they persist.
A prediction or machine state stamped off the node's clock (:mod:`thermal_comp_common.stamp_guard`)
is refused, counted on ``/diagnostics``, logged once per burst, never applied; one behind the last
is acknowledged like a bad prediction, one ahead never. The watchdog also counts the wall seconds
since an acceptable prediction arrived, whatever the stamps say.
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

from thermal_comp_common.frames import MACHINE_BASE_FRAME
from thermal_comp_common.runtime.diagnostics import DiagnosticsPublisher
from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, SENSOR_QOS, TOPIC_ERRORS_PREDICTED,
                                       TOPIC_MACHINE_STATE, TOPIC_OFFSETS, TOPIC_SIM_SYNC,
                                       declare_parameters, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_common.stamp_guard import (Refusal, StampCheck, StampGuard, default_max_ahead_s,
                                             graph_clock_s, stamp_values)
from thermal_comp_msgs.msg import AxisOffsets, MachineState, SimSync, ThermalErrors

from cnc_bridge.audit_log import AuditLog
from cnc_bridge.bridge_core import (ACTIVATION_REFUSED, NOT_CONFIRMED, POSITIONS_ASSUMED, RAMP_DONE,
                                    TRANSFORM_FAILED, WRITE_FAILED, BridgeCore, BridgeUpdate)
from cnc_bridge.status import bridge_status
from cnc_bridge.bridge_params import (PARAMS, RUNTIME, changed_envelope, envelope_config,
                                      loosening)
from cnc_bridge.credentials import SECRET_NAMES
from cnc_bridge.error_transform import ANGULAR_COMPONENTS, HtmGeometry, load_lathe_tools
from cnc_bridge.offset_backend import make_backend
from cnc_bridge.safety_envelope import EnvelopeConfigError, SafetyEnvelope, flag_names
from cnc_bridge.update_profile import UpdateProfile

#: the launcher drives configure/activate/deactivate of a node module that says this
LIFECYCLE_NODE = True

SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
#: wall-clock period at which a backend whose I/O runs in the node's thread is served between
#: writes (OPC UA: health check, keep-alive, positions, reconnection), s
SERVE_PERIOD_S = 0.05
#: wall-clock period at which the ``/diagnostics`` values are refreshed from the core, s (off
#: the offsets' path: an update only counts, it formats nothing)
DIAGNOSE_PERIOD_S = 1.0


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
        bound = default_max_ahead_s(self._p["max_stamp_ahead_s"], bool(self.get_parameter("use_sim_time").value))
        self.stamps = {t: StampGuard(t, bound) for t in (TOPIC_ERRORS_PREDICTED, TOPIC_MACHINE_STATE)}
        self.envelope: SafetyEnvelope | None = None
        self.backend = None
        self.audit: AuditLog | None = None
        self.core: BridgeCore | None = None   # the write path of a configured node
        self.adopted = []                 # HeldAdoption per axis from the last configure
        self._entities = []               # publishers, subscriptions, timer of a configured node
        self.offsets_pub = self.sync_pub = None
        #: timed only with profile_path: between predictions (no begin) its laps do nothing
        self.profile = UpdateProfile()
        backend = self._p["backend"]
        self.diag = DiagnosticsPublisher(self, hardware_id=(
            f"CNC {self._p['endpoint']}" if backend == "opcua" else "machine_sim (twin backend)"))
        self.create_timer(DIAGNOSE_PERIOD_S, self._diagnose, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._diagnose()
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
            lathe = load_lathe_tools(p["lathe_tools_file"])
            self.audit = AuditLog(p["audit_log_path"]) if p["audit_log_path"] else None
            self.backend = make_backend(p)
        except (ValueError, OSError, ConnectionError) as exc:
            self._configure_error = str(exc)
            self.get_logger().error(f"configure failed, nothing written: {exc}")
            self._release()
            self._diagnose()
            return FAILURE
        self.core = BridgeCore(
            self.envelope, self.backend, self.audit, kinematic=self.kinematic,
            sphere_radius_mm=p["sphere_radius_mm"], lathe=lathe, htm=self.htm,
            convention=p["htm_convention"], positions_required=p["positions_required"],
            profile=self.profile, now=lambda: self.get_clock().now().nanoseconds * 1e-9,
            report=self._report)
        # audited by the core; the first offsets message after activation carries the flags
        self.adopted = self.core.adopt_held()
        for a in self.adopted:
            text = "start-up: " + a.describe()
            if a.flags:      # rclpy: one severity per call site
                self.get_logger().warning(text)
            else:
                self.get_logger().info(text)
        self._positions: dict[str, float] = {}
        self._errors: dict[str, float] | None = None
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
        self._configure_error = ""
        self._diagnose()
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        refused = self.core.activate(bool(self.get_parameter("enable").value))
        if refused is not None:         # logged and audited by the core: stays inactive
            self._diagnose()
            return FAILURE
        # what start-up allocated (modules, the client, the node) stays out of the garbage
        # collector's passes: a full collection over it is a pause on the offsets' path
        gc.freeze()
        self._audit_event("", f"activate: compensation {'enabled' if self.envelope.enabled else 'DISABLED'}")
        self.get_logger().info(f"active: writing offsets from "
                               f"{self._fmt(self.envelope.applied)} (rate-limited)")
        self._diagnose()
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        ramping_down = self.core.deactivate()
        text = (f"deactivate: compensation off, offsets ramp to zero at "
                f"{self.envelope.config.disable_ramp_um_per_s} um/s from {self._fmt(self.envelope.applied)}")
        self._audit_event("", text)
        self.get_logger().info(text)
        if ramping_down and not self._p["lockstep"] and \
                not self.get_parameter("use_sim_time").value:
            self._ramp_down_for(self._p["deactivate_wait_s"])
        self._diagnose()
        return SUCCESS

    def _ramp_down_for(self, wait_s: float) -> None:
        """Step the ramp to zero in real time (the executor is ours meanwhile) until every
        offset is at zero or ``wait_s`` passed; the ramp goes on after that on the timer."""
        deadline = time.monotonic() + wait_s
        while self.core.ramping_down and time.monotonic() < deadline:
            # pacing a physical ramp in wall time: the rate limit is per second of real time
            time.sleep(min(self._p["update_period_s"], max(0.0, deadline - time.monotonic())))
            t = self.get_clock().now().nanoseconds * 1e-9
            self._update(t, s_to_stamp(t), fresh=False)
        if self.core.ramping_down:
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
        if self.core is not None:
            self.core.active = self.core.ramping_down = False
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
        self.core = None
        if why:
            self._diagnose()

    @staticmethod
    def _fmt(values: dict[str, float]) -> str:
        return ", ".join(f"{a}={v:.3f} {'um/m' if a in ANGULAR_COMPONENTS else 'um'}"
                         for a, v in sorted(values.items())) or "nothing"

    def _audit_event(self, axis: str, text: str, flags: int = 0) -> None:
        if self.core is not None:
            self.core.audit_event(axis, text, flags)

    def _report(self, kind: str, text: str) -> None:
        """The core's problems in the log; rclpy throttles per call site, so one per kind."""
        log = self.get_logger()
        if kind == TRANSFORM_FAILED:
            log.error(text, throttle_duration_sec=10.0)
        elif kind == WRITE_FAILED:
            log.error(text, throttle_duration_sec=10.0)
        elif kind == NOT_CONFIRMED:
            log.warning(text, throttle_duration_sec=5.0)
        elif kind == POSITIONS_ASSUMED:
            log.warning(text)
        elif kind == RAMP_DONE:
            log.info(text)
        elif kind == ACTIVATION_REFUSED:
            log.error(text)
        else:
            log.error(text)

    def _diagnose(self) -> None:
        """The ``bridge`` status (:func:`~cnc_bridge.status.bridge_status`)."""
        level, message, values = bridge_status(
            self.core, self.backend, self._p, self._state_machine.current_state[1],
            stamp_values(self.stamps.values()), any(g.in_burst for g in self.stamps.values()),
            self._configure_error, self._fmt)
        self.diag.set("bridge", level, message, **values)

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
    def _stamp_check(self, topic: str, t: float) -> StampCheck:
        """The stamp ``t`` of a message on ``topic`` against the node's clock (refusals counted)."""
        check = self.stamps[topic].check(t, graph_clock_s(self.get_clock().now().nanoseconds))
        if check.log:
            self.get_logger().warning(check.text)
        if not check.accepted or check.burst_over:
            self._diagnose()
        return check

    def _on_state(self, msg: MachineState) -> None:
        t = stamp_to_s(msg.header.stamp)
        if not self._stamp_check(TOPIC_MACHINE_STATE, t).accepted:
            return
        if len(msg.axis_names) != len(msg.axis_positions):
            self.get_logger().error(
                f"machine_state: {len(msg.axis_names)} axis_names but "
                f"{len(msg.axis_positions)} axis_positions; ignored")
            return
        self._positions = dict(zip(msg.axis_names, msg.axis_positions))
        fresh_t, timeout = self.envelope.last_fresh_t, self._p["watchdog_timeout_s"]
        if (self._writing and self._p["lockstep"] and fresh_t is not None
                and (t - fresh_t > timeout or (self.core.silent_s() or 0.0) > timeout)):
            self._update(t, msg.header.stamp, fresh=False)

    def _on_prediction(self, msg: ThermalErrors) -> None:
        t = stamp_to_s(msg.header.stamp)
        stamp = self._stamp_check(TOPIC_ERRORS_PREDICTED, t)
        if stamp.refusal is Refusal.BEHIND:
            self._ack(msg)       # answered like a bad prediction, never applied
        if not stamp.accepted:
            return
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
        self._ack(msg)
        self.profile.lap("ack")
        self.profile.end()

    def _ack(self, msg: ThermalErrors) -> None:
        """Lock-step: the prediction of this instant is handled."""
        if self.sync_pub is not None:
            self.sync_pub.publish(SimSync(header=Header(stamp=msg.header.stamp),
                                          node_name=self.get_name(),
                                          processed_until=msg.header.stamp))

    @property
    def _active(self) -> bool:
        """Writes follow the predictions."""
        return self.core is not None and self.core.active

    @property
    def _writing(self) -> bool:
        """Active, or deactivated with offsets still ramping to zero."""
        return self.core is not None and self.core.writing

    def _on_timer(self) -> None:
        if not self._writing:
            return
        t = self.get_clock().now().nanoseconds * 1e-9
        last = self.core.last_update_t
        if last is not None and t - last < self._p["update_period_s"]:
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
    def _update(self, t: float, stamp, fresh: bool) -> None:
        """One core update with the last good prediction; its offsets published with ``stamp``."""
        update = self.core.update(t, self._errors, self._positions, fresh,
                                  publish=lambda u: self.offsets_pub.publish(self._offsets_msg(u, stamp)))
        if update is not None:
            self.get_logger().debug(" ".join(f"{a.axis}={a.read_back_um} [{flag_names(a.flags)}]"
                                             for a in update.axes))

    @staticmethod
    def _offsets_msg(update: BridgeUpdate, stamp) -> AxisOffsets:
        msg = AxisOffsets(header=Header(stamp=stamp, frame_id=MACHINE_BASE_FRAME), compensation_enabled=update.compensation_enabled)
        for a in update.axes:
            msg.axis_names.append(a.axis)
            msg.commanded_offsets_um.append(a.commanded_um)
            msg.applied_offsets_um.append(a.applied_um)
            msg.applied.append(a.confirmed)
            msg.limits_hit.append(a.flags)
        return msg

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
