"""``talc_model`` node: an adaptive thermal-error model (TALC, AGP or CD) in the loop.

Run: ``python -m talc_model.talc_model_node --ros-args -p model_kind:=talc
-p model_config:=talc.yaml -p state_path:=nmv5000/model.json``

The loop itself is :class:`talc_model.loop.closed_loop.ClosedLoop` (ROS-free); this node wires it:
``temperatures`` (non-OK sensors -> NaN: excluded and held, listed in ModelStatus; a reading flagged OK
but not finite or outside -50..150 degC is refused the same way, counted, logged once per burst, on
``/diagnostics`` status ``readings``: :mod:`talc_model.loop.reading_check`), ``machine_state``
(flattened inputs) and ``offsets`` (what the bridge applied: :mod:`talc_model.loop.applied_compensation`)
in; ``errors/predicted``, ``errors/measured``, ``model_status``, ``/diagnostics`` and the lock-step
``SimSync`` ack out. When the model asks for a probe, a ``ProbeCycle`` goal starts and the ack of
t_k is withheld until its result is in (or its wall-clock deadline passed: cancelled, failed).
Failed, rejected, aborted, cancelled or timed-out cycles are counted and never learned from.

Persistence: the state is saved atomically after every probing cycle, every ``save_period_s`` of
model time and at shutdown, and resumed at start. The periodic save waits for the bridge's offsets
answering its instant (then acks it; :mod:`talc_model.save_schedule`): it stays off the
temperature-to-offsets path. **A resumed state saved at a model time after
the graph's first instant** (another run, e.g. a cell started twice with the same state_path) is
refused with one error naming the file and both times, moved aside (``*.refused-t<s>.json``,
nothing deleted), and the node starts fresh (``pretrained_path`` or a new model, calibration phase)
so the lock-step goes on; it never retries the refused state.

Online learning: the ``adopt_prior`` service (AdoptPrior) takes a prior learned by the online learner;
:mod:`talc_model.online.prior_swap` checks it, warms a model from it over the run's history and
swaps it in between two instants (audited in ``audit_path``). docs/learn.md, "Online learning".

Stamps: a message on ``temperatures``, ``machine_state`` or ``offsets`` stamped more than
``max_stamp_ahead_s`` ahead of the node's clock, or not finite, or (temperatures, machine state)
behind the last accepted one, is refused (:mod:`thermal_comp_common.stamp_guard`): never
modelled, never acknowledged, never saved; counted on ``/diagnostics`` (status ``stamps``),
logged once per burst.
"""
from __future__ import annotations

import gc
import math
import pathlib
import time

import yaml
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Time
from rclpy.action import ActionClient
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from thermal_comp_common.frames import MACHINE_BASE_FRAME
from thermal_comp_common.runtime.diagnostics import DiagnosticsPublisher
from thermal_comp_common.machine_inputs import machine_state_inputs
from thermal_comp_common.sensor_readings import model_temperatures
from thermal_comp_common.stamp_guard import StampGuard, admit, default_max_ahead_s, graph_clock_s, stamp_status
from thermal_comp_common.runtime.node_runtime import (ACTION_PROBE_CYCLE, EVENT_QOS, LATCHED_QOS, SENSOR_QOS,
                                              TOPIC_ERRORS_MEASURED, TOPIC_ERRORS_PREDICTED,
                                              TOPIC_MACHINE_STATE, TOPIC_MODEL_STATUS, TOPIC_OFFSETS,
                                              TOPIC_SIM_SYNC, TOPIC_TEMPERATURES,
                                              declare_parameters, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import (AxisOffsets, MachineState, ModelStatus, SimSync,
                                   TemperatureArray, ThermalErrors)
from thermal_comp_msgs.srv import AdoptPrior

from talc_model.adaptive_model import ANGULAR_COMPONENTS, make_model
from talc_model.loop.applied_compensation import BridgeCompensation
from talc_model.loop.closed_loop import ClosedLoop, ResumedState, ResumedStateMismatch, StepKind
from talc_model.loop.instant_inputs import InputsReady, InstantInputs
from talc_model.loop.reading_check import ReadingCheck
from talc_model.model_node_params import MODEL_NODE_PARAMS
from talc_model.model_persistence import load_model, load_pretrained, save_model
from talc_model.online.history import RunHistory
from talc_model.online.learner import SERVICE_ADOPT_PRIOR
from talc_model.online.prior_swap import PriorSwap, resume_config
from talc_model.probing.cycle_state import Action, ProbeOutcome, ProbeState, ProbingStateMachine
from talc_model.save_schedule import SaveNow, SaveSchedule
from talc_model.state_files import move_aside, resolve_state_path, run_identity, saved_time_s

SIM_SYNC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
PHASES = {"calibration": ModelStatus.PHASE_CALIBRATION, "compensation": ModelStatus.PHASE_COMPENSATION,
          "no_good": ModelStatus.PHASE_NO_GOOD}

PARAMS = MODEL_NODE_PARAMS


def _load_yaml(path: str) -> dict:
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
        self.state_path = resolve_state_path(p["state_path"])
        # a state saved after an online swap resumes with the configuration adopted with it
        self.config = resume_config(self.state_path, _load_yaml(p["model_config"]) if p["model_config"] else {})
        resumed = None
        from_state = self.state_path is not None and self.state_path.is_file()
        if from_state:
            # a state of another machine type, twin or inputs is refused in one line
            model = load_model(self.state_path, expected_kind=self.kind,
                               expected=run_identity(self.config, self._fresh_model()[0]))
            how = f"resumed from {self.state_path}"
            saved = saved_time_s(self.state_path, model)
            resumed = ResumedState(str(self.state_path), saved) if saved is not None else None
        else:
            model, how = self._fresh_model()
        cfg = getattr(model, "config", None)
        self.angular = set(getattr(cfg, "angular_components", ANGULAR_COMPONENTS))
        self.wall = Clock(clock_type=ClockType.STEADY_TIME)

        self.pred_pub = self.create_publisher(ThermalErrors, TOPIC_ERRORS_PREDICTED, EVENT_QOS)
        self.meas_pub = self.create_publisher(ThermalErrors, TOPIC_ERRORS_MEASURED, EVENT_QOS)
        self.status_pub = self.create_publisher(ModelStatus, TOPIC_MODEL_STATUS, LATCHED_QOS)
        self.sync_pub = (self.create_publisher(SimSync, TOPIC_SIM_SYNC, SIM_SYNC_QOS)
                         if p["lockstep_participant"] else None)
        self.diag = DiagnosticsPublisher(self, hardware_id=f"{self.kind} model")
        self.probe_client = ActionClient(self, ProbeCycle, ACTION_PROBE_CYCLE)
        self.create_subscription(TemperatureArray, TOPIC_TEMPERATURES, self._on_temperatures, SENSOR_QOS)
        self.create_subscription(MachineState, TOPIC_MACHINE_STATE, self._on_machine_state, SENSOR_QOS)
        self.create_subscription(AxisOffsets, TOPIC_OFFSETS, self._on_offsets, EVENT_QOS)
        self.create_timer(0.2, self._on_wall_timer, clock=self.wall)

        self.sink = BridgeCompensation(model.component_names, p["applied_compensation"],
                                       publish=self._publish_prediction)
        self.loop = ClosedLoop(model, self.sink, live=True, resumed=resumed,
                               probing=ProbingStateMachine(p["offsets_wait_s"], p["probe_result_wait_s"]))
        # online learning: a learned prior is checked, warmed over the run's history and swapped in
        self.online: PriorSwap | None = None      # off unless asked for: no service to attack, no history kept
        if p["online_learning"]:
            self.online = PriorSwap(self.kind, self.config, p["prior_path"],
                                    RunHistory(p["history_max_instants"], complete=not from_state),
                                    p["warm_events_per_instant"], p["audit_path"], self.state_path)
            self.create_service(AdoptPrior, SERVICE_ADOPT_PRIOR, self._on_adopt_prior)
        self.machine_state: dict[str, float] = {}
        self.instant_inputs = InstantInputs(p["machine_state_wait_s"])
        self.pending: tuple[float, dict[str, float]] | None = None   # temperatures waiting for their state
        self.excluded: list[str] = []
        self.readings = ReadingCheck()
        self.last_pred_msg: ThermalErrors | None = None
        self.saves = SaveSchedule(p["save_period_s"], p["offsets_wait_s"])
        self.probe_goal_handle = None
        self.ack_pending_t: float | None = None
        bound = default_max_ahead_s(p["max_stamp_ahead_s"], bool(self.get_parameter("use_sim_time").value))
        # the bridge's offsets are stamped by its timer too: not forward-only
        self.stamps = {TOPIC_TEMPERATURES: StampGuard(TOPIC_TEMPERATURES, bound),
                       TOPIC_MACHINE_STATE: StampGuard(TOPIC_MACHINE_STATE, bound),
                       TOPIC_OFFSETS: StampGuard(TOPIC_OFFSETS, bound, forward_only=False)}
        self.diag.set("state", "OK", how)
        self._stamp_status()
        self._readings_status()
        self.get_logger().info(f"{self.kind} model: {how}; components {', '.join(model.component_names)}")
        # what start-up allocated (modules, the model, the node) stays out of the garbage
        # collector's passes: a full collection over it is a pause on the predictions' path
        gc.freeze()

    @property
    def model(self):
        return self.loop.model

    def _fresh_model(self):
        if self.p["prior_path"]:
            # heavy: scipy.signal, scikit-learn only with a prior
            from talc_model.prior.talc import load_prior
            from talc_model.prior.dispatch import model_from_prior
            return model_from_prior(self.kind, self.config, load_prior(self.p["prior_path"])), f"prior {self.p['prior_path']}"
        if self.p["pretrained_path"]:
            # a trained model of another twin or inputs is refused in one line
            return (load_pretrained(self.p["pretrained_path"], self.config, expected_kind=self.kind,
                                    expected=run_identity(self.config, make_model(self.kind, self.config))),
                    f"pre-trained from {self.p['pretrained_path']}")
        return make_model(self.kind, self.config), "new model"

    # ------------------------------------------------------------------ inputs
    def _stamp_ok(self, topic: str, t: float) -> bool:
        """The stamp ``t`` of a message on ``topic`` is on the graph's clock (else refused, counted)."""
        check, refresh = admit(self.stamps[topic], t, graph_clock_s(self.get_clock().now().nanoseconds),
                               self.get_logger().warning)
        if refresh:
            self._stamp_status()
        return check.accepted

    def _stamp_status(self) -> None:
        level, text, values = stamp_status(self.stamps.values(),
                                           max_ahead_s=self.stamps[TOPIC_TEMPERATURES].max_ahead_s)
        self.diag.set("stamps", level, text, **values)

    def _on_machine_state(self, msg: MachineState) -> None:
        if not self._stamp_ok(TOPIC_MACHINE_STATE, stamp_to_s(msg.header.stamp)):
            return
        self.machine_state = machine_state_inputs(msg)
        self.instant_inputs.state_arrived(stamp_to_s(msg.header.stamp))
        self.sink.b_pos = self.machine_state.get("B_pos", 0.0)
        if self.pending is not None and self.instant_inputs.state_t >= self.pending[0] - 1e-6:
            self._model_instant(*self._take_pending())

    def _on_offsets(self, msg: AxisOffsets) -> None:
        if not self._stamp_ok(TOPIC_OFFSETS, stamp_to_s(msg.header.stamp)):
            return
        ok = len(msg.axis_names) == len(msg.applied_offsets_um)
        self.sink.on_offsets(stamp_to_s(msg.header.stamp), msg.compensation_enabled,
                             dict(zip(msg.axis_names, msg.applied_offsets_um)) if ok else None)
        limited = [a for a, f in zip(msg.axis_names, msg.limits_hit)
                   if f & (AxisOffsets.LIMIT_ABSOLUTE | AxisOffsets.LIMIT_RATE)]
        if limited:
            self.get_logger().warning(f"bridge limited the offsets of {limited}: the applied compensation "
                                      f"differs from the prediction", throttle_duration_sec=60.0)
        if self.loop.offsets_arrived(self.sink.stamp_s, self._wall_s()) is Action.SEND_GOAL:
            self._send_goal()
        if self.saves.offsets_arrived(self.sink.stamp_s):
            self._deferred_save()

    def _temperatures(self, msg: TemperatureArray, t: float) -> dict[str, float] | None:
        n = len(msg.sensor_ids)
        if len(msg.temperatures_degc) != n or len(msg.status) != n:
            self.get_logger().error(f"temperatures at {t:.3f} s: {n} sensor_ids, {len(msg.temperatures_degc)} "
                                    f"values, {len(msg.status)} status entries: ignored")
            return None
        verdict = self.readings.check(t, msg.sensor_ids, msg.temperatures_degc, msg.status)
        if verdict.log:
            self.get_logger().warning(verdict.text)
        if verdict.invalid or verdict.burst_over:
            self._readings_status()
        temps, self.excluded = model_temperatures(msg.sensor_ids, msg.temperatures_degc, verdict.status)
        return temps

    def _readings_status(self) -> None:
        burst = self.readings.in_burst
        self.diag.set("readings", "WARN" if burst else "OK",
                      "refusing temperature readings flagged OK but not plausible" if burst
                      else "temperature readings plausible", **self.readings.values())

    def _step(self, t: float, temps: dict[str, float]):
        args = (t, temps, self.machine_state, self._wall_s(), self.sink.must_wait_for(t))
        try:
            return self.loop.step(*args)
        except ResumedStateMismatch as exc:
            self._refuse_state(exc)
            return self.loop.step(*args)

    def _on_temperatures(self, msg: TemperatureArray) -> None:
        t = stamp_to_s(msg.header.stamp)
        if not self._stamp_ok(TOPIC_TEMPERATURES, t):
            return
        temps = self._temperatures(msg, t)
        if temps is None:
            return
        if not self._inputs_ready(t):
            self.pending = (t, temps)   # modelled when its state arrives, or after the bounded wait
            return
        self.pending = None
        self._model_instant(t, temps)

    def _take_pending(self) -> tuple[float, dict[str, float]]:
        pending, self.pending = self.pending, None
        return pending

    def _model_instant(self, t: float, temps: dict[str, float]) -> None:
        """Model the temperatures of instant t, publish, save when due, acknowledge."""
        step = self._step(t, temps)
        if step.kind is StepKind.LATE:
            self.get_logger().warning(f"temperatures stamped {t:.3f} s before the last ({self.loop.t_last:.3f} s): "
                                      f"ignored", throttle_duration_sec=10.0)
            return
        if step.kind is StepKind.REPEAT:
            # machine_sim re-sent this instant (an acknowledgement was missing, e.g. a node
            # restarted): the same prediction goes out again, never a second update
            self.pred_pub.publish(self.last_pred_msg)
        elif step.kind is StepKind.REJECTED:
            self.get_logger().error(f"model input at {t:.3f} s rejected: {step.error}")
        else:
            if step.action is Action.SEND_GOAL:
                self._send_goal()
            self._publish_status(t)
            self._online_step(t, temps)
            if self.saves.on_instant(t, self._wall_s(), self.sink.offsets_seen, self.sink.stamp_s,
                                     self.loop.probing.busy) is SaveNow.NOW:
                self._save(t)
        self._ack(t)

    def _inputs_ready(self, t: float) -> bool:
        """Lock-step: model t only with its machine state, waiting at most ``machine_state_wait_s``."""
        if self.sync_pub is None:
            return True
        if (self.instant_inputs.state_t < t - 1e-6
                and self.count_publishers(self.resolve_topic_name(TOPIC_MACHINE_STATE)) == 0):
            return True   # nobody publishes a machine state (e.g. a bag without one): nothing to wait for
        ready = self.instant_inputs.ready(t, self._wall_s())
        if ready is InputsReady.STEP_HELD:
            self.get_logger().warning(f"no machine_state for t={t:.0f} s within {self.p['machine_state_wait_s']} s: "
                                      f"modelling it with the last inputs")
        return ready is not InputsReady.WAIT

    def _refuse_state(self, exc: ResumedStateMismatch) -> None:
        """The documented choice: refuse, keep the file aside, start fresh (never retry it)."""
        aside = move_aside(pathlib.Path(exc.state_path), exc.saved_time_s) \
            if pathlib.Path(exc.state_path).is_file() else None
        model, how = self._fresh_model()
        self.loop.replace_model(model)
        if self.online is not None:
            self.online.history.restart()
        what = f"{exc}; moved aside to {aside}; starting with a {how}"
        self.get_logger().error(what)
        self.diag.set("state", "WARN", what, state_path=exc.state_path, saved_time_s=exc.saved_time_s,
                      graph_time_s=exc.graph_time_s)

    # ------------------------------------------------------------------ outputs
    def _errors_msg(self, t: float, source: int, values: dict, stds: dict) -> ThermalErrors:
        names = list(self.model.component_names)
        return ThermalErrors(
            header=Header(stamp=s_to_stamp(t), frame_id=MACHINE_BASE_FRAME), source=source, model_kind=self.kind,
            component_names=names, values=[float(values.get(c, math.nan)) for c in names],
            units=[ThermalErrors.UNIT_UM_PER_M if c in self.angular else ThermalErrors.UNIT_UM for c in names],
            uncertainties=[float(stds.get(c, math.nan)) for c in names])

    def _publish_prediction(self, t: float, values, stds) -> None:
        self.last_pred_msg = self._errors_msg(t, ThermalErrors.SOURCE_PREDICTED, values, stds)
        self.pred_pub.publish(self.last_pred_msg)

    def _publish_status(self, t: float) -> None:
        st = self.model.status(t)
        due = st.next_probing_due_s
        excluded = sorted(set(st.excluded_sensor_ids) | set(self.excluded))
        self.status_pub.publish(ModelStatus(
            header=Header(stamp=s_to_stamp(t), frame_id=MACHINE_BASE_FRAME), model_kind=self.kind, phase=PHASES[st.phase],
            probing_cycles=st.probing_cycles, failed_probing_cycles=st.failed_probing_cycles,
            no_good_phases=st.no_good_phases, parameter_updates=st.parameter_updates,
            training_samples=st.training_samples, q_prod_pct=float(st.q_prod_pct),
            next_probing_due=s_to_stamp(due) if math.isfinite(due) and due >= 0 else Time(),
            max_uncertainty=float(st.max_uncertainty), excluded_sensor_ids=excluded, message=st.message))
        self.diag.set("model", "WARN" if st.phase == "no_good" else "OK", f"phase {st.phase}",
                      model_time_s=t, q_prod_pct=round(float(st.q_prod_pct), 3),
                      probing_cycles=st.probing_cycles, failed_probing_cycles=st.failed_probing_cycles,
                      excluded_sensors=",".join(excluded))

    def _ack(self, t: float) -> None:
        """Acknowledge t to machine_sim, unless a probing cycle or a deferred save holds the clock."""
        if self.sync_pub is None:
            return
        if self.loop.probing.busy or self.saves.pending:
            self.ack_pending_t = t if self.ack_pending_t is None else max(self.ack_pending_t, t)
            return
        stamp = s_to_stamp(t)
        self.sync_pub.publish(SimSync(header=Header(stamp=stamp), node_name=self.get_name(),
                                      processed_until=stamp))

    # ------------------------------------------------------------------ probing (ProbeCycle action)
    def _send_goal(self) -> None:
        t = self.loop.probing.t_s
        self.loop.goal_sent()
        if not self.probe_client.server_is_ready() and \
                not self.probe_client.wait_for_server(timeout_sec=self.p["action_server_wait_s"]):
            self._finish(self.loop.probe_failed(t, "no probe_cycle action server"))
            return
        goal = ProbeCycle.Goal()
        goal.artefact = ProbeCycle.Goal.ARTEFACT_GUIDE_BUSH if self.p["artefact"] == "guide_bush" \
            else ProbeCycle.Goal.ARTEFACT_SPHERE
        goal.set_reference = self.model.status(t).probing_cycles == 0
        goal.points_per_indexing = int(self.p["points_per_indexing"])
        goal.timeout_s = float(self.p["probe_timeout_s"])
        goal.tool_position = self.p["tool_position"]
        future = self.probe_client.send_goal_async(goal)
        future.add_done_callback(lambda f, t=t: self._on_goal_response(f, t))

    def _on_goal_response(self, future, t: float) -> None:
        handle = future.result()
        if handle is None or not handle.accepted:
            self._finish(self.loop.probe_failed(t, "probing goal rejected"))
            return
        if self.loop.accepted(t):       # False: timed out meanwhile
            self.probe_goal_handle = handle
            handle.get_result_async().add_done_callback(lambda f, t=t: self._on_result(f, t))

    def _on_result(self, future, t: float) -> None:
        if not (self.loop.probing.busy and self.loop.probing.t_s == t):
            return  # timed out meanwhile: never learned from
        wrapped = future.result()
        res, status = wrapped.result, wrapped.status
        if status != GoalStatus.STATUS_SUCCEEDED or not res.success:
            self._finish(self.loop.probe_failed(t, res.message or f"probing cycle ended with status {status}"))
            return
        e = res.errors
        if len(e.component_names) != len(e.values):
            self._finish(self.loop.probe_failed(
                t, f"result has {len(e.component_names)} component names and {len(e.values)} values"))
            return
        outcome = self.loop.probe_result(t, dict(zip(e.component_names, e.values)))
        if outcome is not None and outcome.success:
            self.meas_pub.publish(ThermalErrors(
                header=Header(stamp=s_to_stamp(t), frame_id=MACHINE_BASE_FRAME), source=ThermalErrors.SOURCE_MEASURED,
                model_kind=e.model_kind or "probe", component_names=list(e.component_names),
                values=list(e.values), units=list(e.units), uncertainties=list(e.uncertainties)))
        self._finish(outcome, res.message)

    def _finish(self, outcome: ProbeOutcome | None, message: str = "") -> None:
        """A cycle ended (None: stale event, nothing to do): save, report, release the ack."""
        if outcome is None:
            return
        t = outcome.t_s
        if self.online is not None:
            self.online.history.probe(t, outcome.success, outcome.measured, outcome.applied, outcome.reason)
        if outcome.success:
            self.diag.set("probing", "OK", f"probing at {t:.0f} s: {message}")
        else:
            self.get_logger().warning(f"probing cycle at {t:.0f} s failed (not learned from): {outcome.reason}")
            self.diag.set("probing", "WARN", f"probing at {t:.0f} s failed: {outcome.reason}")
        self.probe_goal_handle = None
        self._save(t)
        self._publish_status(max(t, self.loop.t_last))
        self._release_ack()

    def _release_ack(self) -> None:
        pending, self.ack_pending_t = self.ack_pending_t, None
        if pending is not None:
            self._ack(pending)

    def _on_wall_timer(self) -> None:
        if self.pending is not None and self._inputs_ready(self.pending[0]):
            self._model_instant(*self._take_pending())
        if self.saves.overdue(self._wall_s()):
            self.get_logger().warning(f"no offsets for t={self.saves.pending_t:.0f} s within "
                                      f"{self.p['offsets_wait_s']} s: saving the state and acknowledging")
            self._deferred_save()
        waited_offsets = self.loop.probing.state is ProbeState.WAIT_OFFSETS
        action, outcome = self.loop.tick(self._wall_s())
        if action is Action.SEND_GOAL:
            if waited_offsets:
                self.get_logger().warning(f"no offsets for t={self.loop.probing.t_s:.0f} s within "
                                          f"{self.p['offsets_wait_s']} s: probing with the last ones")
            self._send_goal()
        elif action is Action.CANCEL_GOAL:
            if self.probe_goal_handle is not None:
                self.probe_goal_handle.cancel_goal_async()
            self._finish(outcome)

    def _wall_s(self) -> float:
        return self.wall.now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ online learning (talc_model.online)
    def _online_step(self, t: float, temps: dict[str, float]) -> None:
        if self.online is None:
            return
        self.online.history.instant(t, temps, self.machine_state)
        swapped = self.online.step(t, self.loop.probing.busy)
        if swapped is not None:          # between two instants: the next one is the new model's
            self.loop.replace_model(swapped.model)
            self.config = swapped.config
            self.get_logger().info(f"online learning: {swapped.audit['reason']}")
            self.diag.set("prior", "OK", swapped.audit["reason"], sha256=self.online.current_sha256)

    def _on_adopt_prior(self, req, resp):
        resp = self.online.answer(req, resp, self.model.component_names, self.loop.t_last)
        (self.get_logger().info if resp.accepted else self.get_logger().warning)(f"adopt_prior: {resp.message}")
        return resp

    # ------------------------------------------------------------------ persistence
    def _deferred_save(self) -> None:
        """The periodic save held back from the offsets' path; then the held ack goes out."""
        self._save(self.loop.t_last)     # the model's state is that of its last instant
        self._release_ack()

    def _save(self, t: float) -> None:
        self.saves.saved(t)
        if self.state_path is None:
            return
        try:
            save_model(self.state_path, self.model, extra={"saved_wall_time": time.time(), "model_time_s": t})
        except OSError as exc:
            self.get_logger().error(f"could not save the model state to {self.state_path}: {exc}")

    def close(self) -> None:
        if self.state_path is not None and math.isfinite(self.loop.t_last):
            self._save(self.loop.t_last)


def main(args=None) -> int:
    return run_node(TalcModelNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
