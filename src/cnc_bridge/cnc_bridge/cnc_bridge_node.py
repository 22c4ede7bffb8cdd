"""The ``cnc_bridge`` node: predicted errors -> bounded, rate-limited offsets on the machine.

Thin ROS shell around :mod:`error_transform`, :mod:`safety_envelope`, :mod:`audit_log` and a
:mod:`cnc_backend` (``twin`` or ``opcua``). Run: ``python -m cnc_bridge.cnc_bridge_node``.

* subscribes ``errors/predicted`` (ThermalErrors, EVENT_QOS) and ``machine_state``
  (MachineState, SENSOR_QOS: axis positions X, Y, Z [mm], B [deg] for eq. 6.3-6.5; with the
  ``opcua`` backend the CNC's own position nodes are used for axes machine_state lacks);
* every prediction: transform at the current positions, one envelope step at the
  prediction's stamp, write + read-back, one audit line per axis, publish ``offsets``
  (AxisOffsets) stamped with the prediction's stamp, then, with ``lockstep``, SimSync
  ``processed_until`` = that stamp (docs/architecture.md);
* between predictions the envelope keeps stepping, so rate-limited moves complete and the
  watchdog can act: without lock-step on a timer (``update_period_s``, node clock); with
  lock-step on ``machine_state`` instants once the last prediction is older than
  ``watchdog_timeout_s`` (deterministic in simulated time);
* ``enable`` may be changed at run time (``ros2 param set`` equivalent): disabling ramps
  the offsets to zero at ``disable_ramp_um_per_s``.
Bad predictions (missing component, wrong unit, NaN) are logged naming the component and
skipped; nothing already applied changes, and the watchdog takes over if they persist.
"""
from __future__ import annotations

import math

from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from thermal_comp_common.node_runtime import (EVENT_QOS, SENSOR_QOS, TOPIC_ERRORS_PREDICTED,
                                       TOPIC_MACHINE_STATE, TOPIC_OFFSETS, TOPIC_SIM_SYNC, Param,
                                       declare_parameters, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_msgs.msg import AxisOffsets, MachineState, SimSync, ThermalErrors

from cnc_bridge.audit_log import AuditLog
from cnc_bridge.cnc_backend import TwinBackend
from cnc_bridge.error_transform import (ANGULAR_COMPONENTS, CONVENTION_RIGID, CONVENTIONS,
                              DEFAULT_SPHERE_RADIUS_MM, FIVE_AXIS_COMPONENTS, HtmGeometry, LatheToolOffsets,
                              TransformInputError, offsets_from_errors)
from cnc_bridge.safety_envelope import LIMIT_WRITE_FAILED, EnvelopeConfig, SafetyEnvelope, flag_names

PARAMS = [
    Param("backend", "twin", "where offsets go: twin = published for machine_sim; opcua = a CNC",
          choices=("twin", "opcua")),
    Param("endpoint", "opc.tcp://127.0.0.1:4840/thermal-comp/cnc", "opcua: server endpoint URL"),
    Param("node_map_file", "", "opcua: YAML node-id map (empty = SINUMERIK-like default layout)"),
    Param("offset_axes", ["X", "Y", "Z"], "opcua default map: axes with compensation nodes"),
    Param("lathe_tools_file", "", "lathe: YAML {tls_component, tools: {T01_X: {intercept_um, gain}}}"),
    Param("sphere_radius_mm", DEFAULT_SPHERE_RADIUS_MM, "d/2 of eq. 6.3-6.5 (E_R0T reference radius), mm",
          lo=1.0, hi=5000.0),
    Param("htm_convention", CONVENTION_RIGID, "eq. 6.3-6.5 as rigid-body HTM consistent with the "
          "probe cycle (eq. 5.10 signs) or exactly as printed", choices=CONVENTIONS),
    Param("htm_origin_mm", [0.0, 0.0, 0.0], "machine X, Y, Z at B = 0 of the point the errors are "
          "defined at (C axis in the probing sphere's centre plane), mm"),
    Param("b_pivot_xz_mm", [0.0, 0.0], "X, Z of the B (swivel) axis line, mm"),
    Param("positions_required", False, "true: no offsets until X, Y, Z positions are known; false: "
          "axes nobody reports are taken at the HTM origin (position terms vanish), logged once"),
    Param("enable", True, "compensation enabled (false ramps the offsets to zero)"),
    Param("abs_limit_um", 30.0, "per-axis absolute offset limit, um", lo=0.0, hi=1000.0),
    Param("compensation_mode", "axis_offsets",
          "axis_offsets: X/Y/Z offsets at the current axis positions (eq. 6.3-6.5, SINUMERIK "
          "SD43900-like); kinematic: the seven location errors are written as parameters of the "
          "CNC's kinematic model, which applies them at every position (angular errors included); "
          "the 'axes' of AxisOffsets are then the component names, in um or um/m",
          choices=("axis_offsets", "kinematic")),
    Param("abs_limit_um_per_m", 50.0, "kinematic mode: absolute limit of the angular parameters "
          "E_A0C E_B0C E_C0C, um/m (the linear ones use abs_limit_um)", lo=0.0, hi=10000.0),
    Param("max_rate_um_per_s", 0.5, "maximum offset change per second (cf. MD32760), um/s",
          lo=1e-6, hi=1000.0),
    Param("max_step_s", 600.0, "longest time step one update may use for the rate limit, s "
          "(covers a lock-step simulation step; in real time the timer steps every update_period_s)",
          lo=1e-3, hi=3600.0),
    Param("watchdog_timeout_s", 900.0, "no fresh prediction for this long: hold, s", lo=1e-3, hi=1e6),
    Param("watchdog_hold_s", 300.0, "watchdog: hold this long before ramping to zero, s", lo=0.0, hi=1e6),
    Param("watchdog_ramp_um_per_s", 0.05, "watchdog: ramp to zero at this rate (0 = hold forever), um/s",
          lo=0.0, hi=1000.0),
    Param("disable_ramp_um_per_s", 0.5, "ramp rate to zero when disabled, um/s", lo=1e-6, hi=1000.0),
    Param("update_period_s", 1.0, "without lock-step: envelope update period between predictions, s",
          lo=1e-3, hi=3600.0),
    Param("lockstep", False, "publish SimSync after the offsets answering each prediction"),
    Param("audit_log_path", "", "append-only CSV of every write (empty = no audit log)"),
    Param("connect_timeout_s", 10.0, "opcua: wait this long for the first connection at start, s",
          lo=0.0, hi=600.0),
    Param("request_timeout_s", 2.0, "opcua: deadline of one write/read request, s", lo=0.01, hi=60.0),
    Param("user", "", "opcua: user name (empty = anonymous)"),
    Param("password", "", "opcua: password of user"),
    Param("certificate", "", "opcua: client certificate for Basic256Sha256 Sign&Encrypt"),
    Param("private_key", "", "opcua: private key of the client certificate"),
    Param("server_certificate", "", "opcua: expected server certificate (empty = from the endpoint)"),
    Param("security_required", False, "opcua: refuse any connection without Sign&Encrypt"),
]


def _make_backend(node: Node, p: dict):
    if p["backend"] == "twin":
        return TwinBackend()
    from cnc_bridge.opcua_backend import OpcUaBackend, OpcUaConfig, default_node_map, load_node_map
    if p["node_map_file"]:
        node_map, scale = load_node_map(p["node_map_file"])
    else:
        axes = tuple(a for a in p["offset_axes"] if a)
        if p["compensation_mode"] == "kinematic" and axes == ("X", "Y", "Z"):
            axes = FIVE_AXIS_COMPONENTS   # one CNC parameter per location error
        node_map, scale = default_node_map(axes), 0.001
    backend = OpcUaBackend(OpcUaConfig(
        endpoint=p["endpoint"], node_map=node_map, offset_units_per_um=scale,
        user=p["user"] or None, password=p["password"] if p["user"] else None,
        certificate=p["certificate"] or None, private_key=p["private_key"] or None,
        server_certificate=p["server_certificate"] or None,
        security_required=p["security_required"], timeout_s=p["request_timeout_s"]))
    if p["connect_timeout_s"] > 0 and not backend.wait_connected(p["connect_timeout_s"]):
        node.get_logger().warning(
            f"not connected to {p['endpoint']} yet ({backend.last_error}); writes fail and are "
            f"flagged until the connection is up")
    return backend


class CncBridgeNode(Node):
    def __init__(self, context=None):
        super().__init__("cnc_bridge", context=context)
        p = declare_parameters(self, PARAMS)
        self._p = p
        self.kinematic = p["compensation_mode"] == "kinematic"
        angular_limits = {c: p["abs_limit_um_per_m"] for c in ANGULAR_COMPONENTS} if self.kinematic else {}
        self.envelope = SafetyEnvelope(EnvelopeConfig(
            abs_limit_um=p["abs_limit_um"], axis_abs_limits_um=angular_limits,
            max_rate_um_per_s=p["max_rate_um_per_s"],
            max_step_s=p["max_step_s"], watchdog_timeout_s=p["watchdog_timeout_s"],
            watchdog_hold_s=p["watchdog_hold_s"], watchdog_ramp_um_per_s=p["watchdog_ramp_um_per_s"],
            disable_ramp_um_per_s=p["disable_ramp_um_per_s"]), enabled=p["enable"])
        self.lathe = None
        if p["lathe_tools_file"]:
            import yaml
            try:
                with open(p["lathe_tools_file"]) as f:
                    self.lathe = LatheToolOffsets.from_mapping(yaml.safe_load(f))
            except (OSError, yaml.YAMLError) as exc:
                raise ValueError(f"parameter 'lathe_tools_file': {exc}") from exc
        if len(p["htm_origin_mm"]) != 3 or len(p["b_pivot_xz_mm"]) != 2:
            raise ValueError(f"parameters 'htm_origin_mm' (3 values) / 'b_pivot_xz_mm' (2 values): "
                             f"got {list(p['htm_origin_mm'])} / {list(p['b_pivot_xz_mm'])}")
        self.htm = HtmGeometry(tuple(p["htm_origin_mm"]), tuple(p["b_pivot_xz_mm"]))
        self.audit = AuditLog(p["audit_log_path"]) if p["audit_log_path"] else None
        self.backend = _make_backend(self, p)
        held = self.backend.held_offsets() if hasattr(self.backend, "held_offsets") else {}
        if any(abs(v) > 0 for v in held.values()):
            self.envelope.adopt_held(held)
            self.get_logger().info("continuing from the offsets the CNC holds: " +
                                   ", ".join(f"{a}={v:.3f}" for a, v in sorted(held.items())))
        self._positions: dict[str, float] = {}
        self._errors: dict[str, float] | None = None
        self._last_update_t: float | None = None
        self._warned_positions = False
        self.offsets_pub = self.create_publisher(AxisOffsets, TOPIC_OFFSETS, EVENT_QOS)
        self.sync_pub = (self.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
                         if p["lockstep"] else None)
        self.create_subscription(MachineState, TOPIC_MACHINE_STATE, self._on_state, SENSOR_QOS)
        self.create_subscription(ThermalErrors, TOPIC_ERRORS_PREDICTED, self._on_prediction, EVENT_QOS)
        if not p["lockstep"]:
            self.create_timer(p["update_period_s"], self._on_timer)
        self.add_post_set_parameters_callback(self._on_params_set)
        self.get_logger().info(
            f"cnc_bridge: backend {p['backend']}, limit {p['abs_limit_um']} um, rate "
            f"{p['max_rate_um_per_s']} um/s, watchdog {p['watchdog_timeout_s']} s, "
            f"{'enabled' if p['enable'] else 'DISABLED'}")

    # ------------------------------------------------------------------ inputs
    def _on_params_set(self, params: list[Parameter]) -> None:
        for prm in params:
            if prm.name == "enable":
                self.envelope.set_enabled(bool(prm.value))
                self.get_logger().info(f"compensation {'enabled' if prm.value else 'disabled'}")

    def _on_state(self, msg: MachineState) -> None:
        if len(msg.axis_names) != len(msg.axis_positions):
            self.get_logger().error(
                f"machine_state: {len(msg.axis_names)} axis_names but "
                f"{len(msg.axis_positions)} axis_positions; ignored")
            return
        self._positions = dict(zip(msg.axis_names, msg.axis_positions))
        t = stamp_to_s(msg.header.stamp)
        fresh_t = self.envelope.last_fresh_t
        if (self._p["lockstep"] and fresh_t is not None
                and t - fresh_t > self._p["watchdog_timeout_s"]):
            self._update(t, msg.header.stamp, fresh=False)

    def _on_prediction(self, msg: ThermalErrors) -> None:
        t = stamp_to_s(msg.header.stamp)
        try:
            self._errors = self._errors_from(msg)
            fresh = True
        except ValueError as exc:
            # keep what is applied (the watchdog takes over if this persists), but still
            # answer t_k so that a lock-step simulation does not stall on a bad message
            self.get_logger().error(f"errors/predicted at t={t:.3f}: {exc}; prediction skipped")
            fresh = False
        self._update(t, msg.header.stamp, fresh=fresh)
        if self.sync_pub is not None:
            self.sync_pub.publish(SimSync(header=Header(stamp=msg.header.stamp),
                                          node_name=self.get_name(),
                                          processed_until=msg.header.stamp))

    def _on_timer(self) -> None:
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
        try:
            decisions = self.envelope.step(t, commanded, fresh)
        except ValueError as exc:
            self.get_logger().error(f"offsets at t={t:.3f}: {exc}; holding")
            return
        self._last_update_t = t
        if not decisions:
            return
        try:
            readback = self.backend.write_offsets({d.axis: d.applied_um for d in decisions})
        except ValueError as exc:            # e.g. an axis without an offset node in the map
            self.get_logger().error(f"offsets at t={t:.3f} not written: {exc}",
                                    throttle_duration_sec=10.0)
            readback = {d.axis: None for d in decisions}
        msg = AxisOffsets(header=Header(stamp=stamp), compensation_enabled=self.envelope.enabled)
        entries = []
        for d in decisions:
            back = readback.get(d.axis)
            self.envelope.confirm(d.axis, back)
            flags = d.flags | (LIMIT_WRITE_FAILED if back is None else 0)
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
        if self.audit is not None:
            self.audit.log_write(t, entries)
        self.offsets_pub.publish(msg)
        self.get_logger().debug(" ".join(f"{e[0]}={e[2]} [{flag_names(e[3])}]" for e in entries))

    def close(self) -> None:
        self.backend.close()
        if self.audit is not None:
            self.audit.close()


def main(args=None) -> int:
    return run_node(CncBridgeNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
