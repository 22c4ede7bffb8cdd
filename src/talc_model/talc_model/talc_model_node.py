"""``talc_model`` node: an adaptive thermal-error model (TALC or AGP) in the loop.

Run: ``python -m talc_model.talc_model_node --ros-args -p model_kind:=talc
-p model_config:=talc.yaml -p state_path:=/var/lib/thermal-comp/talc.json``

Wiring (the model itself is the pure core behind :class:`adaptive_model.AdaptiveModel`):

- ``temperatures`` (TemperatureArray) at t_k: every sensor whose status is not OK is passed
  to the model as NaN, i.e. **excluded and held**: the model keeps its last good value for
  that input (TALC) and the sensor is listed in ``ModelStatus.excluded_sensor_ids``. Then
  the node predicts for t_k and publishes ``errors/predicted`` (with uncertainties) and
  ``model_status``; if ``probe_due(t_k)``, it starts a ``ProbeCycle`` goal and withholds its
  lock-step ``SimSync`` ack for t_k until the result is in; otherwise it acks t_k at once.
- ``machine_state`` (MachineState): flattened to numeric inputs (``<spindle>_rpm``,
  ``<rotary>_axis_rpm``, ``<axis>_pos``, ``<drive>_power_w``, ``coolant_on``,
  ``coolant_temperature_degc``, ``door_open``, ``machine_busy_probing``).
- ``offsets`` (AxisOffsets): whether compensation is active at the CNC. **Applied
  compensation in component space**: the models work on error components (E_X0C ..),
  while the bridge turns them into axis offsets. The node keeps the last *predicted*
  component values it published as the applied compensation, provided the bridge reports
  ``compensation_enabled``; with no ``offsets`` message yet, or compensation disabled, the
  applied compensation is zero (parameter ``applied_compensation``: ``offsets`` | ``predicted``
  | ``none``). The probe measures true error minus applied compensation in component space
  when the twin applies the same transform, so total error = measured + applied holds.
  Clamping or rate limiting in the bridge makes this approximate; such limits are logged.
- A successful probing result is published on ``errors/measured`` and learned from; failed,
  rejected, aborted, cancelled or timed-out cycles are counted and never learned from.
- Persistence: the model state is saved atomically (``state_path``) after every probing
  cycle, every ``save_period_s`` of model time and at shutdown; at start an existing state
  is resumed (no new calibration phase), else ``pretrained_path`` or a fresh model.
"""
from __future__ import annotations

from thermal_comp_common.machine_inputs import machine_state_inputs

import math
import pathlib
import time

from builtin_interfaces.msg import Time
from rclpy.action import ActionClient
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from thermal_comp_common.node_runtime import (ACTION_PROBE_CYCLE, EVENT_QOS, LATCHED_QOS, SENSOR_QOS,
                                       TOPIC_ERRORS_MEASURED, TOPIC_ERRORS_PREDICTED,
                                       TOPIC_MACHINE_STATE, TOPIC_MODEL_STATUS, TOPIC_OFFSETS,
                                       TOPIC_SIM_SYNC, TOPIC_TEMPERATURES, Param,
                                       declare_parameters, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import (AxisOffsets, MachineState, ModelStatus, SimSync,
                                   TemperatureArray, ThermalErrors)

from talc_model.adaptive_model import ANGULAR_COMPONENTS, make_model
from talc_model.model_persistence import load_model, load_pretrained, save_model

SIM_SYNC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
PHASES = {"calibration": ModelStatus.PHASE_CALIBRATION, "compensation": ModelStatus.PHASE_COMPENSATION,
          "no_good": ModelStatus.PHASE_NO_GOOD}

PARAMS = [
    Param("model_kind", "talc", "adaptive model", choices=("talc", "agp", "cd")),
    Param("model_config", "", "YAML file with the model's configuration (empty = defaults)"),
    Param("state_path", "", "JSON file for the model state (resumed at start; empty = no persistence)"),
    Param("pretrained_path", "", "state of a trained model to start from when state_path has none"),
    Param("save_period_s", 3600.0, "save the state at least this often (model time), s", 1.0, 1e7),
    Param("artefact", "sphere", "probing artefact", choices=("sphere", "guide_bush")),
    Param("tool_position", "", "lathe: tool position probed (e.g. GB)"),
    Param("points_per_indexing", 0, "touch points per C indexing; 0 = the server's default", 0, 100),
    Param("probe_timeout_s", 0.0, "cycle timeout in simulated time sent with the goal; 0 = server default",
          0.0, 86400.0),
    Param("probe_result_wait_s", 600.0, "wall-clock wait for a probing result before the cycle is "
          "cancelled and counted as failed, s", 0.1, 86400.0),
    Param("action_server_wait_s", 10.0, "wall-clock wait for the probe_cycle action server, s", 0.0, 3600.0),
    Param("offsets_wait_s", 2.0, "wall-clock wait for the bridge's offsets answering t_k before a "
          "probe starts (only once offsets have been seen), s", 0.0, 600.0),
    Param("applied_compensation", "offsets", "how the applied compensation is known",
          choices=("offsets", "predicted", "none")),
    Param("lockstep_participant", False, "publish SimSync for t_k after the prediction for t_k"),
]


def _load_yaml(path: str) -> dict:
    import yaml
    p = pathlib.Path(path)
    if not p.is_file():
        raise ValueError(f"parameter 'model_config': {path!r} is not a file")
    try:
        data = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"parameter 'model_config': {path!r} is not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"parameter 'model_config': {path!r} must hold a mapping, got {type(data).__name__}")
    return data


class TalcModelNode(Node):
    def __init__(self, context=None):
        super().__init__("talc_model", context=context)
        p = declare_parameters(self, PARAMS)
        self.p = p
        self.kind = p["model_kind"]
        config = _load_yaml(p["model_config"]) if p["model_config"] else {}
        self.state_path = pathlib.Path(p["state_path"]) if p["state_path"] else None
        if self.state_path is not None and self.state_path.is_file():
            self.model = load_model(self.state_path, expected_kind=self.kind)
            how = f"resumed from {self.state_path}"
        elif p["pretrained_path"]:
            self.model = load_pretrained(p["pretrained_path"], config, expected_kind=self.kind)
            how = f"pre-trained from {p['pretrained_path']}"
        else:
            self.model = make_model(self.kind, config)
            how = "new model"
        cfg = getattr(self.model, "config", None)
        self.angular = set(getattr(cfg, "angular_components", ANGULAR_COMPONENTS))
        self.wall = Clock(clock_type=ClockType.STEADY_TIME)

        self.pred_pub = self.create_publisher(ThermalErrors, TOPIC_ERRORS_PREDICTED, EVENT_QOS)
        self.meas_pub = self.create_publisher(ThermalErrors, TOPIC_ERRORS_MEASURED, EVENT_QOS)
        self.status_pub = self.create_publisher(ModelStatus, TOPIC_MODEL_STATUS, LATCHED_QOS)
        self.sync_pub = (self.create_publisher(SimSync, TOPIC_SIM_SYNC, SIM_SYNC_QOS)
                         if p["lockstep_participant"] else None)
        self.probe_client = ActionClient(self, ProbeCycle, ACTION_PROBE_CYCLE)
        self.create_subscription(TemperatureArray, TOPIC_TEMPERATURES, self._on_temperatures, SENSOR_QOS)
        self.create_subscription(MachineState, TOPIC_MACHINE_STATE, self._on_machine_state, SENSOR_QOS)
        self.create_subscription(AxisOffsets, TOPIC_OFFSETS, self._on_offsets, EVENT_QOS)
        self.create_timer(0.2, self._on_wall_timer, clock=self.wall)

        self.machine_state: dict[str, float] = {}
        self.excluded: list[str] = []
        self.last_predicted: dict[str, float] = {}
        self.last_pred_msg: ThermalErrors | None = None
        self.offsets_seen = False
        self.applied_offsets: dict[str, float] = {}
        self.offsets_stamp_s = -math.inf
        self.compensation_enabled = False
        self.t_last = -math.inf
        self.last_save_t = -math.inf
        # probing: one cycle at a time
        self.probe_t: float | None = None          # t_k of the cycle being prepared / running
        self.probe_applied: dict[str, float] = {}
        self.probe_goal_handle = None
        self.probe_stage = ""                       # "wait_offsets" | "wait_accept" | "running"
        self.probe_deadline = math.inf
        self.ack_pending_t: float | None = None
        self.probes_started = 0
        self.get_logger().info(f"{self.kind} model: {how}; components "
                               f"{', '.join(self.model.component_names)}")

    # ------------------------------------------------------------------ inputs
    def _on_machine_state(self, msg: MachineState) -> None:
        self.machine_state = machine_state_inputs(msg)

    def _on_offsets(self, msg: AxisOffsets) -> None:
        self.offsets_seen = True
        self.offsets_stamp_s = max(self.offsets_stamp_s, stamp_to_s(msg.header.stamp))
        self.compensation_enabled = bool(msg.compensation_enabled)
        if len(msg.axis_names) == len(msg.applied_offsets_um):
            self.applied_offsets = {a: float(v) for a, v in zip(msg.axis_names, msg.applied_offsets_um)
                                    if math.isfinite(v)}
        limited = [a for a, f in zip(msg.axis_names, msg.limits_hit)
                   if f & (AxisOffsets.LIMIT_ABSOLUTE | AxisOffsets.LIMIT_RATE)]
        if limited:
            self.get_logger().warning(f"bridge limited the offsets of {limited}: the applied compensation "
                                      f"differs from the prediction", throttle_duration_sec=60.0)
        if self.probe_stage == "wait_offsets" and self.offsets_stamp_s >= self.probe_t:
            self._send_goal()

    def _on_temperatures(self, msg: TemperatureArray) -> None:
        t = stamp_to_s(msg.header.stamp)
        if t < self.t_last:
            self.get_logger().warning(f"temperatures stamped {t:.3f} s before the last ({self.t_last:.3f} s): "
                                      f"ignored", throttle_duration_sec=10.0)
            return
        if t == self.t_last and self.last_pred_msg is not None:
            # machine_sim re-sent this instant (an acknowledgement was missing, e.g. a node
            # restarted): the model has learned from it already, so the same prediction goes
            # out again unchanged and the instant is acknowledged again; never a second update
            self.pred_pub.publish(self.last_pred_msg)
            self._ack(t)
            return
        n = len(msg.sensor_ids)
        if len(msg.temperatures_degc) != n or len(msg.status) != n:
            self.get_logger().error(f"temperatures at {t:.3f} s: {n} sensor_ids, {len(msg.temperatures_degc)} "
                                    f"values, {len(msg.status)} status entries: ignored")
            return
        temps, excluded = {}, []
        for sid, v, st in zip(msg.sensor_ids, msg.temperatures_degc, msg.status):
            if st == TemperatureArray.STATUS_OK and math.isfinite(v):
                temps[sid] = float(v)
            else:
                temps[sid] = math.nan
                excluded.append(sid)
        self.excluded = excluded
        self.t_last = t
        try:
            self.model.update_inputs(t, temps, self.machine_state)
            values, stds = self.model.predict(t)
        except ValueError as exc:
            self.get_logger().error(f"model input at {t:.3f} s rejected: {exc}")
            self._ack(t)
            return
        self._publish_prediction(t, values, stds)
        if self.probe_t is None and self.model.probe_due(t):
            self._start_probe(t)
        self._publish_status(t)
        if t - self.last_save_t >= self.p["save_period_s"]:
            self._save(t)
        self._ack(t)

    # ------------------------------------------------------------------ outputs
    def _errors_msg(self, t: float, source: int, values: dict, stds: dict) -> ThermalErrors:
        names = list(self.model.component_names)
        return ThermalErrors(
            header=Header(stamp=s_to_stamp(t)), source=source, model_kind=self.kind,
            component_names=names, values=[float(values.get(c, math.nan)) for c in names],
            units=[ThermalErrors.UNIT_UM_PER_M if c in self.angular else ThermalErrors.UNIT_UM for c in names],
            uncertainties=[float(stds.get(c, math.nan)) for c in names])

    def _publish_prediction(self, t: float, values: dict, stds: dict) -> None:
        self.last_pred_msg = self._errors_msg(t, ThermalErrors.SOURCE_PREDICTED, values, stds)
        self.pred_pub.publish(self.last_pred_msg)
        self.last_predicted = dict(values)

    def _publish_status(self, t: float) -> None:
        st = self.model.status(t)
        due = st.next_probing_due_s
        excluded = sorted(set(st.excluded_sensor_ids) | set(self.excluded))
        self.status_pub.publish(ModelStatus(
            header=Header(stamp=s_to_stamp(t)), model_kind=self.kind, phase=PHASES[st.phase],
            probing_cycles=st.probing_cycles, failed_probing_cycles=st.failed_probing_cycles,
            no_good_phases=st.no_good_phases, parameter_updates=st.parameter_updates,
            training_samples=st.training_samples, q_prod_pct=float(st.q_prod_pct),
            next_probing_due=s_to_stamp(due) if math.isfinite(due) and due >= 0 else Time(),
            max_uncertainty=float(st.max_uncertainty), excluded_sensor_ids=excluded, message=st.message))

    def _ack(self, t: float) -> None:
        """Acknowledge t to machine_sim, unless a probing cycle holds the clock."""
        if self.sync_pub is None:
            return
        if self.probe_t is not None:
            self.ack_pending_t = t if self.ack_pending_t is None else max(self.ack_pending_t, t)
            return
        stamp = s_to_stamp(t)
        self.sync_pub.publish(SimSync(header=Header(stamp=stamp), node_name=self.get_name(),
                                      processed_until=stamp))

    # ------------------------------------------------------------------ probing
    def _applied_compensation(self) -> dict[str, float]:
        """The compensation the probe will see as applied, per model component.

        ``offsets`` mode uses what the CNC really holds (read back by the bridge): with the
        bridge in kinematic mode the offsets are the components themselves; with X/Y/Z axis
        offsets, a probing cycle sees them as a translation of the table frame only
        (``cnc_bridge.error_transform.applied_offsets_in_component_space``): adding back the
        whole prediction would count never-applied angular compensation as learned error.
        ``predicted`` assumes the last prediction was applied in full."""
        mode = self.p["applied_compensation"]
        names = self.model.component_names
        if mode == "none" or (mode == "offsets" and not (self.offsets_seen and self.compensation_enabled)):
            return {c: 0.0 for c in names}
        if mode == "offsets" and self.applied_offsets:
            if any(c in self.applied_offsets for c in names):
                return {c: self.applied_offsets.get(c, 0.0) for c in names}
            if any(a in self.applied_offsets for a in ("X", "Y", "Z")):
                from cnc_bridge.error_transform import applied_offsets_in_component_space
                comp = applied_offsets_in_component_space(self.applied_offsets,
                                                          self.machine_state.get("B_pos", 0.0))
                return {c: comp.get(c, 0.0) for c in names}
        return {c: (v if math.isfinite(v) else 0.0) for c, v in self.last_predicted.items()}

    def _start_probe(self, t: float) -> None:
        self.probe_t = t
        self.probes_started += 1
        if self.p["applied_compensation"] == "offsets" and self.offsets_seen and self.offsets_stamp_s < t:
            # let the bridge apply the prediction for t first, so that the probe sees it
            self.probe_stage = "wait_offsets"
            self.probe_deadline = self._wall_s() + self.p["offsets_wait_s"]
            return
        self._send_goal()

    def _send_goal(self) -> None:
        t = self.probe_t
        self.probe_applied = self._applied_compensation()
        if not self.probe_client.server_is_ready() and \
                not self.probe_client.wait_for_server(timeout_sec=self.p["action_server_wait_s"]):
            self._probe_failed("no probe_cycle action server")
            return
        goal = ProbeCycle.Goal()
        goal.artefact = ProbeCycle.Goal.ARTEFACT_GUIDE_BUSH if self.p["artefact"] == "guide_bush" \
            else ProbeCycle.Goal.ARTEFACT_SPHERE
        goal.set_reference = self.model.status(t).probing_cycles == 0
        goal.points_per_indexing = int(self.p["points_per_indexing"])
        goal.timeout_s = float(self.p["probe_timeout_s"])
        goal.tool_position = self.p["tool_position"]
        self.probe_stage = "wait_accept"
        self.probe_deadline = self._wall_s() + self.p["probe_result_wait_s"]
        future = self.probe_client.send_goal_async(goal)
        future.add_done_callback(lambda f, t=t: self._on_goal_response(f, t))

    def _on_goal_response(self, future, t: float) -> None:
        if self.probe_t != t:
            return  # timed out meanwhile
        handle = future.result()
        if handle is None or not handle.accepted:
            self._probe_failed("probing goal rejected")
            return
        self.probe_goal_handle = handle
        self.probe_stage = "running"
        handle.get_result_async().add_done_callback(lambda f, t=t: self._on_result(f, t))

    def _on_result(self, future, t: float) -> None:
        if self.probe_t != t:
            return  # timed out meanwhile: never learned from
        wrapped = future.result()
        res = wrapped.result
        status = wrapped.status
        from action_msgs.msg import GoalStatus
        if status != GoalStatus.STATUS_SUCCEEDED or not res.success:
            self._probe_failed(res.message or f"probing cycle ended with status {status}")
            return
        e = res.errors
        if not (len(e.component_names) == len(e.values)):
            self._probe_failed(f"result has {len(e.component_names)} component names and {len(e.values)} values")
            return
        measured = dict(zip(e.component_names, e.values))
        try:
            self.model.add_measurement(t, measured, self.probe_applied)
        except ValueError as exc:
            self._probe_failed(f"result not usable: {exc}")
            return
        out = ThermalErrors(header=Header(stamp=s_to_stamp(t)), source=ThermalErrors.SOURCE_MEASURED,
                            model_kind=e.model_kind or "probe", component_names=list(e.component_names),
                            values=list(e.values), units=list(e.units), uncertainties=list(e.uncertainties))
        self.meas_pub.publish(out)
        self._probe_done(t, f"probing at {t:.0f} s: {res.message}")

    def _probe_failed(self, reason: str) -> None:
        t = self.probe_t
        self.get_logger().warning(f"probing cycle at {t:.0f} s failed (not learned from): {reason}")
        self.model.add_failed_measurement(t, reason)
        self._probe_done(t, reason)

    def _probe_done(self, t: float, what: str) -> None:
        self.probe_t = None
        self.probe_goal_handle = None
        self.probe_stage = ""
        self.probe_deadline = math.inf
        self._save(t)
        t_now = max(t, self.t_last)
        self._publish_status(t_now)
        pending, self.ack_pending_t = self.ack_pending_t, None
        if pending is not None:
            self._ack(pending)

    def _on_wall_timer(self) -> None:
        if self.probe_t is None or self._wall_s() < self.probe_deadline:
            return
        if self.probe_stage == "wait_offsets":
            self.get_logger().warning(f"no offsets for t={self.probe_t:.0f} s within "
                                      f"{self.p['offsets_wait_s']} s: probing with the last ones")
            self._send_goal()
            return
        handle = self.probe_goal_handle
        if handle is not None:
            handle.cancel_goal_async()
        self._probe_failed(f"no probing result within {self.p['probe_result_wait_s']} s (cancelled)")

    def _wall_s(self) -> float:
        return self.wall.now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ persistence
    def _save(self, t: float) -> None:
        self.last_save_t = t
        if self.state_path is None:
            return
        try:
            save_model(self.state_path, self.model, extra={"saved_wall_time": time.time(), "model_time_s": t})
        except OSError as exc:
            self.get_logger().error(f"could not save the model state to {self.state_path}: {exc}")

    def close(self) -> None:
        if self.state_path is not None and math.isfinite(self.t_last):
            self._save(self.t_last)


def main(args=None) -> int:
    return run_node(TalcModelNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
