"""machine_sim: the twin as a ROS node that owns simulated time.

Every step it publishes /clock, ``machine_state``, ``twin/sensor_readings`` and (optionally)
``errors/ground_truth`` for the new instant t_k, then advances to t_{k+1}
- in lock-step, once every node in ``lockstep_participants`` has published a SimSync with
  ``processed_until >= t_k`` (docs/architecture.md); it starts once all of them publish on
  ``sim_sync`` and re-sends the current instant (every topic of it, ground truth included)
  when acknowledgements are missing and neither a publish nor a touch probe happened for
  ``resend_after_s`` wall seconds (a subscriber that matched late, a restarted participant;
  a model busy with a probing cycle is alive and is not flooded with copies);
  nothing waits forever: a participant that has not joined, or not acknowledged the instant,
  within ``lockstep_deadline_s`` wall s is named with the instant (log, ``/diagnostics``) and
  ``on_late`` decides: ``stop`` (exit code 3), ``drop`` it, or ``wait`` (docs/reliability.md);
  one gone from the graph for ``participant_gone_s`` is gone on without until it is back, and an
  acknowledgement of an instant never published is ignored and counted
  (:mod:`thermal_twin.sim.lockstep_roster`);
- free-running otherwise, at ``real_time_factor`` (0 = as fast as possible); in lock-step
  ``real_time_factor`` > 0 is a ceiling: an instant is never published sooner than
  ``step_s / real_time_factor`` wall seconds after the previous one.
It keeps the offsets applied by the CNC (``offsets``) and answers ``twin/touch_probe``: the
twin idles for the request's ``duration_s`` (programme paused, hall goes on), then
``thermal_twin.machine.artefact_geometry.touch_trigger_position`` says where the probe triggers
(true error minus applied compensation). The physics is in scenario_runner / simulate.

Run: python -m thermal_twin.machine_sim_node --ros-args -p machine:=nmv5000 -p scenario:=talc-178h-dry
"""
from __future__ import annotations

import math
import time

import numpy as np
from rclpy.clock import Clock as RclClock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from thermal_comp_common.frames import MACHINE_BASE_FRAME
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.diagnostics import ERROR, DiagnosticsPublisher
from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, SENSOR_QOS, SERVICE_TOUCH_PROBE, TOPIC_ERRORS_TRUE,
                                       TOPIC_MACHINE_STATE, TOPIC_OFFSETS, TOPIC_SIM_SYNC, TOPIC_TWIN_SENSORS,
                                       Param, declare_parameters, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_msgs.msg import AxisOffsets, MachineState, SimSync, TemperatureArray, ThermalErrors
from thermal_comp_msgs.srv import TouchProbe
from thermal_twin.machine.schema import load_machine
from thermal_twin.machine.artefact_geometry import touch_trigger_position
from thermal_comp_common.machine_state_fields import error_components, machine_state_fields
from thermal_comp_common.stamp_guard import StampCheck, StampGuard, stamp_status
from thermal_twin.sim.scenario_runner import ScenarioRunner
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.checkpoint import TwinCheckpoint, shared_objects
from thermal_twin.sim.lockstep_roster import LockstepRoster

PARAMS = [
    Param("machine", "nmv5000", "machine preset (nmv5000, swiss-lathe, spindle-stand, fe-three-body) or YAML path"),
    Param("scenario", "talc-178h-dry", "scenario name (thermal-comp sim --help lists them)"),
    Param("seed", 0, "seed of the scenario and of sensor and probe noise", 0, 2**31 - 1),
    Param("hours", 0.0, "scenario duration in hours (0 = the scenario's default)", 0.0, 10000.0),
    Param("step_s", 0.0, "time step in s (0 = the scenario's default)", 0.0, 3600.0),
    Param("publish_ground_truth", True, "publish errors/ground_truth (evaluation only)"),
    # default [""]: a typed string array (an empty list would be typed as bytes by rclpy);
    # empty names are ignored, so the default means free-running
    Param("lockstep_participants", [""],
          "node names that must acknowledge every instant on sim_sync (none = free-running)"),
    Param("wait_for_subscribers", [""],
          "node names (e.g. a bag recorder) that must subscribe to errors/ground_truth before the first "
          "instant: a recorder that starts after the graph would miss the first instants"),
    Param("real_time_factor", 0.0, "simulated s per wall s: the free-running speed, in lock-step a ceiling "
          "(watching live, or faults at a chosen instant); 0 = as fast as possible", 0.0, 1.0e6),
    Param("resend_after_s", 2.0, "lock-step: re-send the current instant after this many wall s without "
          "all acknowledgements", 0.1, 600.0),
    Param("lockstep_deadline_s", 120.0, "lock-step: wall s to wait for a participant to join or to "
          "acknowledge an instant before it is reported late (and on_late applies)", 0.1, 86400.0),
    Param("on_late", "stop", "lock-step: what a late or inconsistent participant causes: stop the graph "
          "(exit code 3), drop it from the lock-step and go on, or wait and report again",
          choices=("stop", "drop", "wait")),
    Param("participant_gone_s", 10.0, "lock-step: wall s a participant may be gone from the graph (no "
          "publisher of its name on sim_sync) before the graph goes on without it; it is re-admitted "
          "when it is back", 0.1, 3600.0),
    Param("max_stamp_ahead_s", 1.0, "refuse offsets stamped more than this ahead of the simulated time "
          "(this node owns it: an honest bridge stamps the instant it answers), s", 0.001, 86400.0),
    Param("probe_offsets_wait_s", 5.0, "a touch probe at instant t_k first waits (wall s, bounded) for the "
          "offsets the bridge wrote for t_k, as a CNC applies them before the probing cycle moves "
          "(0 = measure against whatever offsets arrived)", 0.0, 600.0),
    Param("probe_noise", True, "touch probe repeatability scatter (False: ideal probe, readout still quantised)"),
    Param("shutdown_when_done", False, "stop the node when the scenario has ended"),
    Param("state_path", "", "checkpoint file: written atomically before every published instant and "
          "after every touch probe; an existing one is resumed at start (a restart after a crash "
          "goes on where the twin was, simulated time never runs backwards); empty = none"),
    Param("state_fsync", False, "fsync every checkpoint: it then survives a power loss too, at a few ms "
          "per instant (without, the atomic replace survives a crash or kill of this process)"),
]


class MachineSimNode(Node):
    def __init__(self, context=None):
        super().__init__("machine_sim", context=context)
        # one BLAS thread: the twin's small matrix products gain nothing from a second one, and
        # OpenBLAS's idle workers spin for a while after each call, i.e. on the other core just
        # while the sensors -> model -> bridge path of the instant runs (docs/cnc_bridge.md,
        # latency section; the twin's outputs are bit-identical)
        self._blas_limit = single_thread_blas()
        p = declare_parameters(self, PARAMS)
        self.machine = load_machine(p["machine"])
        timeline = make_timeline(self.machine.name, p["scenario"], hours=p["hours"] or None,
                                 seed=p["seed"], step_s=p["step_s"] or None)
        self.runner = ScenarioRunner(self.machine, timeline, seed=p["seed"])
        self.checkpoint = (TwinCheckpoint(p["state_path"], key={
            k: p[k] for k in ("machine", "scenario", "seed", "hours", "step_s", "probe_noise")},
            fsync=p["state_fsync"], shared=shared_objects(self.runner)) if p["state_path"] else None)
        resumed = self.checkpoint.load() if self.checkpoint is not None else None
        self.roster = LockstepRoster(p["lockstep_participants"] or [], p["participant_gone_s"],
                                     stream=self.resolve_topic_name(TOPIC_SIM_SYNC))
        self.observers = [n for n in (p["wait_for_subscribers"] or []) if n]
        self.publish_truth = p["publish_ground_truth"]
        self.resend_after_s = p["resend_after_s"]
        self.deadline_s = p["lockstep_deadline_s"]
        self.on_late = p["on_late"]
        self.exit_code = 0
        self.shutdown_when_done = p["shutdown_when_done"]
        self.probe_rng = np.random.default_rng([p["seed"], 7]) if p["probe_noise"] else None
        self.units = {e: s.unit for e, s in self.machine.errors.items()}
        self.applied_offsets: dict[str, float] = {}
        self.offsets_wait_s = p["probe_offsets_wait_s"]
        self.offsets_stamp_s: float | None = None      # stamp of the last offsets (None: no bridge yet)
        self.offsets_missed_t: float | None = None     # the instant a touch waited for offsets in vain
        # the bridge stamps its offsets with the instant they answer: not forward-only (its watchdog)
        self.offsets_guard = StampGuard(self.resolve_topic_name(TOPIC_OFFSETS), p["max_stamp_ahead_s"],
                                        forward_only=False)
        if resumed is not None:
            self.runner, self.probe_rng, self.applied_offsets = resumed
        self.started = False
        self.last_publish_wall = 0.0        # wall time of the last publish or touch probe (re-send timer)
        self.wait_since = time.monotonic()   # wall time the current wait (start, instant) began
        self.last_presence_wall = -math.inf  # wall time the graph was last looked at for participants
        self.published_t = -math.inf

        self.pub_clock = self.create_publisher(Clock, "/clock", SENSOR_QOS)
        self.pub_state = self.create_publisher(MachineState, TOPIC_MACHINE_STATE, SENSOR_QOS)
        self.pub_sensors = self.create_publisher(TemperatureArray, TOPIC_TWIN_SENSORS, SENSOR_QOS)
        self.pub_truth = self.create_publisher(ThermalErrors, TOPIC_ERRORS_TRUE, EVENT_QOS)
        self.offsets_sub = self.create_subscription(AxisOffsets, TOPIC_OFFSETS, self._on_offsets, EVENT_QOS)
        self.create_subscription(SimSync, TOPIC_SIM_SYNC, self._on_sync, EVENT_QOS)
        self.create_service(TouchProbe, SERVICE_TOUCH_PROBE, self._on_touch_probe)
        self.diag = DiagnosticsPublisher(self, hardware_id=f"{self.machine.name}/{p['scenario']}")
        self.diag.set("lock-step", "OK", "lock-step with " + ", ".join(self.participants)
                      if self.participants else "free-running", instant_s=self.runner.t_s)
        self._stamp_status()

        # the owner of simulated time paces itself on the steady clock (with use_sim_time a
        # ROS-time timer would wait for the /clock this node has yet to publish)
        self.wall_clock = RclClock(clock_type=ClockType.STEADY_TIME)
        rtf = p["real_time_factor"]
        step = float(timeline.time_s[1] - timeline.time_s[0]) if len(timeline) > 1 else 1.0
        #: lock-step pacing: the least wall time between two published instants (0: none)
        self.min_interval_s = step / rtf if rtf > 0 else 0.0
        if self.participants:
            self.timer = self.create_timer(min(0.05, self.min_interval_s or 0.05), self._lockstep_tick,
                                           clock=self.wall_clock)
        else:
            self.timer = self.create_timer(step / rtf if rtf > 0 else 0.001, self._free_tick, clock=self.wall_clock)
        if resumed is not None:
            self.get_logger().warning(f"resumed from {p['state_path']} at t = {self.runner.t_s:.0f} s "
                                      f"(instant {self.runner.k} of {len(timeline)})")
        self.get_logger().info(
            f"{self.machine.name}/{p['scenario']}: {len(timeline)} instants, "
            f"{'lock-step with ' + ', '.join(self.participants) if self.participants else 'free-running'}")

    def destroy_node(self) -> None:
        self._blas_limit.restore_original_limits()   # an in-process node (tests) leaves BLAS as it was
        super().destroy_node()

    # ------------------------------------------------------------------ publishing
    def _save_checkpoint(self) -> None:
        if self.checkpoint is not None:
            self.checkpoint.save(self.runner, self.probe_rng, self.applied_offsets)

    def _publish_instant(self) -> None:
        r = self.runner
        self._save_checkpoint()   # before publishing: a restart never skips back past t_k
        stamp = s_to_stamp(r.t_s)
        # every message of t_k is built before the first goes out: once the sensor readings
        # are out, the sensors -> model -> bridge path runs, and this process only publishes
        fields = machine_state_fields(r.inputs())
        state = MachineState(machine_busy_probing=r.busy_probing, **fields)
        state.header.stamp, state.header.frame_id = stamp, MACHINE_BASE_FRAME
        readings = r.sensor_readings()
        temps = TemperatureArray(sensor_ids=list(readings), temperatures_degc=list(readings.values()),
                                 status=[TemperatureArray.STATUS_OK] * len(readings))
        temps.header.stamp, temps.header.frame_id = stamp, MACHINE_BASE_FRAME
        truth = None
        if self.publish_truth:
            names, values, codes = error_components(r.errors(), self.units)
            truth = ThermalErrors(source=ThermalErrors.SOURCE_GROUND_TRUTH, model_kind="twin",
                                  component_names=names, values=values, units=codes,
                                  uncertainties=[0.0] * len(values))
            truth.header.stamp, truth.header.frame_id = stamp, MACHINE_BASE_FRAME
        self.pub_clock.publish(Clock(clock=stamp))
        self.pub_state.publish(state)
        self.pub_sensors.publish(temps)
        if truth is not None:
            self.pub_truth.publish(truth)
        self.last_publish_wall = self.wait_since = time.monotonic()
        self.published_t = r.t_s
        self.diag.update_values("lock-step", instant_s=r.t_s)
        self._last_published = (stamp, state, temps, truth)

    def _republish(self) -> None:
        """Send the current instant again (same stamps, same bytes) to late subscribers, on
        every topic of the instant: a restarted recorder gets the ground truth it missed too
        (the recorder keeps one copy). /clock is re-sent at the current simulated time, which
        probing may have moved on: the clock never runs backwards."""
        stamp, state, temps, truth = self._last_published
        self.pub_clock.publish(Clock(clock=s_to_stamp(self.runner.t_s)))
        self.pub_state.publish(state)
        self.pub_sensors.publish(temps)
        if truth is not None:
            self.pub_truth.publish(truth)
        self.last_publish_wall = time.monotonic()

    def _finish_if_done(self) -> bool:
        if not self.runner.done:
            return False
        self.timer.cancel()
        self.get_logger().info(f"scenario finished at t = {self.runner.t_s:.0f} s")
        self.diag.set("lock-step", "OK", "scenario finished", instant_s=self.runner.t_s)
        if self.shutdown_when_done:
            # a reader on another host may not hold the last instants yet: shutting down drops
            # what its reliable writers still owe; wait for the acknowledgements (bounded, 5 s each)
            for pub in (self.pub_clock, self.pub_state, self.pub_sensors, self.pub_truth):
                if not pub.wait_for_all_acked(Duration(seconds=5.0)):
                    self.get_logger().warning(f"{pub.topic_name}: a subscriber did not acknowledge the last "
                                              "messages within 5 s; shutting down without it")
            self.context.try_shutdown()
        return True

    # ------------------------------------------------------------------ free-running
    def _free_tick(self) -> None:
        if not self.started:
            if not self._observers_present():
                return
            self.started = True
            self._publish_instant()
            return
        if self._finish_if_done():
            return
        self.runner.step()
        self._publish_instant()

    # ------------------------------------------------------------------ lock-step
    def _observers_present(self) -> bool:
        """Every node of ``wait_for_subscribers`` has subscribed to the ground-truth topic."""
        if not self.observers:
            return True
        names = {i.node_name for i in
                 self.get_subscriptions_info_by_topic(self.resolve_topic_name(TOPIC_ERRORS_TRUE))}
        return all(n in names for n in self.observers)

    @property
    def participants(self) -> list[str]:
        return self.roster.participants

    def _sync_publishers(self) -> set[str]:
        """Names of the nodes publishing on ``sim_sync`` now (the graph's view)."""
        return {i.node_name for i in self.get_publishers_info_by_topic(self.resolve_topic_name(TOPIC_SIM_SYNC))}

    def _participants_present(self) -> bool:
        names = self._sync_publishers()
        return all(n in names for n in self.participants)

    def _all_acked(self) -> bool:
        """Every active participant has processed the last published instant (probing may have
        moved simulated time on since; the acknowledgement refers to the instant)."""
        return self.roster.all_acked(self.published_t)

    def _due(self) -> bool:
        """Lock-step pacing: the next instant may go out (``real_time_factor`` ceiling)."""
        return time.monotonic() - self.last_publish_wall >= self.min_interval_s

    def _lockstep_tick(self) -> None:
        if not self.started:
            if self._participants_present() and self._observers_present():
                self.started = True
                self._publish_instant()
            elif time.monotonic() - self.wait_since > self.deadline_s:
                self._late(self._absent(), "has not joined the lock-step (no publisher on sim_sync)"
                           " or subscribed to errors/ground_truth")
            return
        self._observe_presence()
        if self._all_acked():
            if self._due():
                self._advance_lockstep()
        elif time.monotonic() - self.wait_since > self.deadline_s:
            self._late(self.roster.unacked(self.published_t), "has not acknowledged it")
        elif time.monotonic() - self.last_publish_wall > self.resend_after_s and not self.runner.done:
            self._republish()

    def _observe_presence(self) -> None:
        """Suspend a participant gone from the graph for ``participant_gone_s``; re-admit it when
        it is back (the graph is looked at every 0.25 wall s)."""
        now = time.monotonic()
        if now - self.last_presence_wall < 0.25 or not self.participants:
            return
        self.last_presence_wall = now
        gone, back = self.roster.observe(self._sync_publishers(), now)
        t = self.published_t
        for n in gone:
            self.get_logger().error(
                f"lock-step: {n} is gone (no publisher of its name on sim_sync for {self.roster.gone_after_s:g} s, "
                f"participant_gone_s) at instant t = {t:.0f} s: the graph goes on without it until it is back")
        for n in back:
            self.get_logger().warning(f"lock-step: {n} is back at instant t = {t:.0f} s: re-admitted, "
                                      "its acknowledgement is awaited again")
        if gone or back:
            self.wait_since = now     # the deadline counts from the change (a returned one catches up)
            suspended = sorted(self.roster.suspended)
            self.diag.set("lock-step", "WARN" if suspended else "OK",
                          f"going on without {', '.join(suspended)} (gone from the graph)" if suspended
                          else "lock-step with " + ", ".join(self.participants),
                          instant_s=t, suspended=",".join(suspended))

    def _absent(self) -> list[str]:
        pubs = self._sync_publishers()
        subs = {i.node_name for i in
                self.get_subscriptions_info_by_topic(self.resolve_topic_name(TOPIC_ERRORS_TRUE))}
        return ([n for n in self.participants if n not in pubs]
                + [n for n in self.observers if n not in subs])

    def _late(self, names: list[str], what: str) -> None:
        """Report late participants by name, with the instant; apply ``on_late``."""
        t = self.published_t if self.started else self.runner.t_s
        waited = time.monotonic() - self.wait_since
        text = (f"lock-step: {', '.join(names)} {what} for instant t = {t:.0f} s "
                f"(waited {waited:.1f} s, lockstep_deadline_s = {self.deadline_s:g}, on_late = {self.on_late})")
        values = dict(instant_s=t, late=",".join(names), waited_s=round(waited, 1))
        if self.on_late == "stop":
            self.get_logger().error(text + ": stopping the graph")
            self.diag.set("lock-step", "ERROR", text, **values)
            self.exit_code = 3
            self.timer.cancel()
            self.context.try_shutdown()
            return
        if self.on_late == "drop":
            self.get_logger().error(text + ": dropped from the lock-step, the graph goes on without it")
            self.diag.set("lock-step", "WARN", f"dropped {', '.join(names)} (late at t = {t:.0f} s)",
                          **values)
            self.roster.drop(names)
            self.observers = [n for n in self.observers if n not in names]
        else:
            self.get_logger().error(text + ": still waiting")
            self.diag.set("lock-step", "ERROR", text, **values)
        self.wait_since = time.monotonic()

    def _on_sync(self, msg: SimSync) -> None:
        t = stamp_to_s(msg.processed_until)
        check = self.roster.ack(msg.node_name, t, self.published_t if self.started else -math.inf)
        if check is not None and not check.accepted:
            self._refused_ack(msg.node_name, check)
            return
        if check is not None and check.burst_over:
            self._stamp_status()
        if self.started and self.participants and self._all_acked() and self._due():
            self._advance_lockstep()

    def _refused_ack(self, claimed: str, check: StampCheck) -> None:
        """An acknowledgement of an instant the graph never published: ignored, named, counted."""
        if check.log:
            others = sorted(self._sync_publishers() - set(self.participants))
            self.get_logger().warning(
                f"lock-step: acknowledgement claiming to be from {claimed!r} ignored ({check.text}); "
                f"instant published last: t = {self.published_t:.0f} s; publishers on sim_sync that are "
                f"no participant: {', '.join(others) if others else 'none'}")
        self._stamp_status()

    def _stamp_status(self) -> None:
        level, text, values = stamp_status((self.roster.ack_guard, self.offsets_guard),
                                           acks_refused=self.roster.ack_guard.refused,
                                           offsets_refused=self.offsets_guard.refused)
        self.diag.set("stamps", level, text, **values)

    def _advance_lockstep(self) -> None:
        if self.diag.level("lock-step") == ERROR:    # a late participant came back (on_late = wait)
            self.get_logger().warning(f"lock-step: every participant acknowledged t = {self.published_t:.0f} s")
            self.diag.set("lock-step", "OK", "lock-step with " + ", ".join(self.participants))
        if self._finish_if_done():
            return
        self.runner.step()
        self._publish_instant()

    # ------------------------------------------------------------------ CNC and probe
    def _on_offsets(self, msg: AxisOffsets) -> None:
        t = stamp_to_s(msg.header.stamp)
        check = self.offsets_guard.check(t, self.runner.t_s)
        if check.log:
            self.get_logger().warning(check.text)
        if not check.accepted or check.burst_over:
            self._stamp_status()
        if not check.accepted:
            return      # a forged stamp neither moves the applied offsets nor stands for an instant
        if len(msg.axis_names) != len(msg.applied_offsets_um):
            self.get_logger().error(f"offsets: {len(msg.axis_names)} axis names but "
                                    f"{len(msg.applied_offsets_um)} applied offsets; message ignored")
            return
        for name, v in zip(msg.axis_names, msg.applied_offsets_um):
            if math.isfinite(v):
                self.applied_offsets[name] = float(v)
            else:
                self.get_logger().error(f"offsets: axis '{name}' applied offset {v!r} is not finite; "
                                        "keeping the previous value")
        self.offsets_stamp_s = t if self.offsets_stamp_s is None else max(t, self.offsets_stamp_s)

    def _offsets_of_this_instant(self) -> None:
        """Before a touch at instant t_k: the offsets the bridge wrote for t_k (a CNC applies
        them before the probing cycle starts). They travel on a topic, the touch request through
        the model and probe_cycle: on a loaded machine the request can arrive first, and the probe
        then measured against the previous instant's compensation (the run's figures changed
        with the load). So they are taken from the subscription here, bounded by
        ``probe_offsets_wait_s`` (no bridge yet, or none publishing now: nothing to wait for), and
        once per instant: the further touches of a cycle whose offsets did not come measure at once
        (a dead bridge held the graph a wait per touch). A coroutine cannot wait instead: the
        events executor the demo uses does not run coroutine callbacks."""
        t = self.published_t
        if self.offsets_missed_t == t:
            return
        bridge = self.count_publishers(self.resolve_topic_name(TOPIC_OFFSETS)) > 0
        end = time.monotonic() + (self.offsets_wait_s if bridge else 0.0)   # none: take what is queued
        while self.offsets_stamp_s is not None and self.offsets_stamp_s < t - 1e-6:
            with self.offsets_sub.handle:
                taken = self.offsets_sub.handle.take_message(AxisOffsets, False)
            if taken is not None:
                self._on_offsets(taken[0])
            elif time.monotonic() >= end:
                self.get_logger().warning(
                    f"touch probe at t = {t:.0f} s: no offsets for this instant "
                    + (f"within probe_offsets_wait_s = {self.offsets_wait_s:g} s" if bridge else "(nobody publishes offsets)")
                    + f" (last stamped {self.offsets_stamp_s:.0f} s); measuring this instant's touches against those")
                self.offsets_missed_t = t
                return
            else:
                time.sleep(0.001)

    def _on_touch_probe(self, request: TouchProbe.Request, response: TouchProbe.Response):
        self._offsets_of_this_instant()
        r = self.runner

        def touch(rng):
            errors = {k[:-3] if k.endswith("_um") else k: v for k, v in r.errors().items()}
            return touch_trigger_position(
                int(request.artefact), float(request.c_axis_deg), float(request.b_axis_deg),
                np.asarray(request.start_mm, dtype=float), np.asarray(request.direction, dtype=float),
                float(request.max_travel_mm), errors, dict(self.applied_offsets), rng=rng)

        try:
            if not (math.isfinite(request.duration_s) and request.duration_s >= 0):
                raise ValueError(f"duration_s: {request.duration_s!r} must be a finite number >= 0")
            touch(None)          # a malformed move is refused before the machine moves
        except ValueError as exc:
            response.triggered = False
            response.trigger_position_mm = [math.nan] * 3
            response.message = f"bad touch-probe request (nothing moved): {exc}"
            response.stamp = s_to_stamp(r.t_s)
            self.get_logger().error(response.message)
            return response
        r.busy_probing = True
        try:
            r.idle(request.duration_s)
            triggered, pos = touch(self.probe_rng)
        finally:
            r.resume()
            r.busy_probing = False
        self._save_checkpoint()   # probing moved simulated time on
        self.last_publish_wall = time.monotonic()   # a probing participant is alive: no re-send yet
        response.triggered = bool(triggered)
        response.trigger_position_mm = [float(x) for x in pos]
        response.message = "" if triggered else f"no trigger within {request.max_travel_mm} mm"
        response.stamp = s_to_stamp(r.t_s)
        self.pub_clock.publish(Clock(clock=response.stamp))
        return response


def main(args=None) -> int:
    return run_node(MachineSimNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
