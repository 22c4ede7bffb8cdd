"""temperature_publisher: calibrated temperatures with per-sensor status on ``temperatures``.

Sources (parameter ``source``):

- ``twin``: raw readings from machine_sim's ``twin/sensor_readings``; publishes for the
  message's instant t_k (every message, or at most every ``period_s`` of sim time).
- ``replay``: a recording CSV. As ``time_master`` the node owns simulated time: it
  publishes ``/clock`` = t_k, then ``temperatures`` stamped t_k, for each row (or every
  ``period_s``), paced by ``real_time_factor`` and, if ``lockstep_participants`` is set,
  waiting for every participant's SimSync >= t_k before t_{k+1}. Otherwise a timer on the
  node clock (use_sim_time with someone else's /clock) samples the recording.
- ``modbus``: RTD modules (register map in the sensor YAML), polled off the executor
  thread; a timer on the node clock publishes the newest readings every ``period_s``.

As a lock-step participant (``lockstep_participant``) the node publishes SimSync for t_k
after ``temperatures`` for t_k. Each sensor's status is on ``/diagnostics`` (``sensor <id>``:
OK, WARN for stale or out of range, ERROR for failed, with the reason), beside a summary
(``sensors``: how many are not ok, frames published).

Stamps (:mod:`thermal_comp_common.stamp_guard`): a twin message stamped more than
``max_stamp_ahead_s`` ahead of the node's clock, behind the last accepted instant, or not finite,
and (time master) an acknowledgement of an instant not yet published, are refused: never
published, acknowledged or counted as progress; counted on ``/diagnostics`` (status ``stamps``),
logged once per burst. Run: ``python -m thermal_sensors.temperature_publisher_node``.
"""
from __future__ import annotations

import logging
import math
import time

import numpy as np
from rclpy.clock import Clock as RclClock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header

from thermal_comp_common.frames import MACHINE_BASE_FRAME
from thermal_comp_common.runtime.diagnostics import DiagnosticsPublisher
from thermal_comp_common.stamp_guard import (Refusal, StampCheck, StampGuard, admit, default_max_ahead_s,
                                              graph_clock_s, stamp_status)
from thermal_comp_common.runtime.node_runtime import (SENSOR_QOS, TOPIC_SIM_SYNC, TOPIC_TEMPERATURES,
                                       TOPIC_TWIN_SENSORS, Param, declare_parameters, run_node,
                                       s_to_stamp, stamp_to_s)
from thermal_comp_msgs.msg import SimSync, TemperatureArray
from thermal_sensors.replay_source import ReplaySource
from thermal_sensors.sensor_config import load_sensor_config, resolve_sensor_config
from thermal_sensors.sensor_status import SensorStatus
from thermal_sensors.temperature_frame import TemperatureFrame, TemperatureFrameBuilder
from thermal_sensors.temperature_source import SOURCE_KINDS
from thermal_sensors.twin_source import TwinSource

#: /diagnostics level of each sensor status
SENSOR_LEVELS = {SensorStatus.OK: "OK", SensorStatus.STALE: "WARN", SensorStatus.OUT_OF_RANGE: "WARN",
                 SensorStatus.FAILED: "ERROR"}
CLOCK_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
SIM_SYNC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)

PARAMS = [
    Param("source", "twin", "where raw readings come from", choices=SOURCE_KINDS),
    Param("sensor_config", "", "sensor YAML (ids, ranges, calibration, stale time, Modbus map) "
          "or a shipped one by name (nmv5000, swiss_lathe, spindle_stand, rtd_bench); "
          "may be empty for replay (every *_c column, uncalibrated)"),
    Param("csv_path", "", "replay: recording CSV in the shared format"),
    Param("period_s", 0.0, "publish period in (sim) seconds; 0 = every twin message / every CSV "
          "row (modbus needs > 0)", lo=0.0, hi=3600.0),
    Param("time_master", False, "replay: publish /clock and own simulated time"),
    Param("real_time_factor", 0.0, "time master: sim seconds per wall second; 0 = as fast as "
          "the lock-step participants keep up", lo=0.0, hi=1e6),
    Param("lockstep_participants", [""], "time master: node names whose SimSync is awaited "
          "before advancing (empty: free-running)"),
    Param("lockstep_participant", False, "publish SimSync for t_k after temperatures for t_k"),
    Param("max_stamp_ahead_s", 0.0, "refuse twin readings stamped more than this ahead of the node's clock, "
          "s; 0 = 60 s on wall time, 3600 s with use_sim_time (data may precede its /clock by a step)",
          0.0, 86400.0),
]
#: a time master's participants acknowledge only instants it published (ns stamps: rounding), s
ACK_TOLERANCE_S = 1e-6


class TemperaturePublisher(Node):
    def __init__(self, context=None):
        super().__init__("temperature_publisher", context=context)
        p = declare_parameters(self, PARAMS)
        self.source_kind = p["source"]
        self.period_s = float(p["period_s"])
        self.lockstep_participant = bool(p["lockstep_participant"])
        self.time_master = bool(p["time_master"])
        self.participants = [n for n in p["lockstep_participants"] if n]
        if self.time_master and self.source_kind != "replay":
            raise ValueError(f"parameter 'time_master': only the replay source can own time "
                             f"(source is {self.source_kind!r})")
        config = (load_sensor_config(resolve_sensor_config(p["sensor_config"]))
                  if p["sensor_config"] else None)
        if config is None and self.source_kind != "replay":
            raise ValueError(f"parameter 'sensor_config': required for source {self.source_kind!r}")

        if self.source_kind == "replay":
            if not p["csv_path"]:
                raise ValueError("parameter 'csv_path': required for source 'replay'")
            self.source = ReplaySource.from_csv(p["csv_path"], config)
            config = self.source.config
        elif self.source_kind == "twin":
            self.source = TwinSource(config)
        else:
            if self.period_s <= 0:
                raise ValueError("parameter 'period_s': must be > 0 for source 'modbus'")
            from thermal_sensors.modbus_source import ModbusSource  # heavy: pymodbus only for source modbus
            logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # failures go to status
            self.source = ModbusSource(config)
            self.source.start()
        self.config = config
        self.builder = TemperatureFrameBuilder(config)
        self._last_status = np.full(len(config.sensors), -1)
        self.diag = DiagnosticsPublisher(self, hardware_id=f"{self.source_kind} sensors")
        self.diag.set("sensors", "OK", f"{len(config.sensors)} sensors, source {self.source_kind}",
                      not_ok=0, frames=0)

        self.pub = self.create_publisher(TemperatureArray, TOPIC_TEMPERATURES, SENSOR_QOS)
        self.sync_pub = (self.create_publisher(SimSync, TOPIC_SIM_SYNC, SIM_SYNC_QOS)
                         if self.lockstep_participant else None)
        self.published = 0
        self.republished = 0
        bound = default_max_ahead_s(p["max_stamp_ahead_s"], bool(self.get_parameter("use_sim_time").value))
        self.stamps: dict[str, StampGuard] = {}
        if self.source_kind == "twin":
            self.stamps["twin"] = StampGuard(self.resolve_topic_name(TOPIC_TWIN_SENSORS), bound)
        if self.time_master and self.participants:   # acknowledgements of several nodes interleave
            self.stamps["acks"] = StampGuard(self.resolve_topic_name(TOPIC_SIM_SYNC), ACK_TOLERANCE_S,
                                             forward_only=False)
        self._stamp_status()
        self._last_msg: TemperatureArray | None = None

        if self.source_kind == "twin":
            self._next_due = -math.inf
            self._last_twin_t = -math.inf
            self.create_subscription(TemperatureArray, TOPIC_TWIN_SENSORS, self._on_twin, SENSOR_QOS)
        elif self.time_master:
            self._setup_time_master(float(p["real_time_factor"]))
        else:
            if self.period_s <= 0:
                raise ValueError("parameter 'period_s': must be > 0 for a replay that is not "
                                 "the time master")
            self.create_timer(self.period_s, self._on_timer)
        self.get_logger().info(
            f"source {self.source_kind}, {len(config.sensors)} sensors "
            f"({', '.join(config.sensor_ids[:8])}{' ...' if len(config.sensors) > 8 else ''})")

    # -- publishing -----------------------------------------------------------------------
    def _publish(self, t_s: float) -> TemperatureFrame:
        frame = self.builder.build(self.source.sample(t_s))
        msg = TemperatureArray(header=Header(stamp=s_to_stamp(t_s), frame_id=MACHINE_BASE_FRAME),
                               sensor_ids=list(frame.sensor_ids),
                               temperatures_degc=[float(v) for v in frame.temperatures_degc],
                               status=[int(s) for s in frame.status])
        self.pub.publish(msg)
        self._last_msg = msg
        self.published += 1
        self._log_status_changes(frame)
        return frame

    def _ack(self, t_s: float) -> None:
        if self.sync_pub is not None:
            stamp = s_to_stamp(t_s)
            self.sync_pub.publish(SimSync(header=Header(stamp=stamp), node_name=self.get_name(),
                                          processed_until=stamp))

    def _log_status_changes(self, frame: TemperatureFrame) -> None:
        """Log and put on /diagnostics each sensor whose status changed; refresh the summary."""
        changed = np.flatnonzero(frame.status != self._last_status)
        for i in changed:
            st = SensorStatus(int(frame.status[i]))
            sid = frame.sensor_ids[i]
            if st == SensorStatus.OK:
                if self._last_status[i] >= 0:
                    self.get_logger().info(f"sensor {sid}: ok again")
                self.diag.set(f"sensor {sid}", "OK", "ok")
            else:
                self.get_logger().warning(f"sensor {sid}: {st.name.lower()}: {frame.reasons[i]}")
                self.diag.set(f"sensor {sid}", SENSOR_LEVELS[st], f"{st.name.lower()}: {frame.reasons[i]}")
        self._last_status = frame.status.astype(int)
        not_ok = int(np.count_nonzero(frame.status != SensorStatus.OK))
        if changed.size:
            self.diag.set("sensors", "WARN" if not_ok else "OK",
                          f"{not_ok} of {len(frame.status)} sensors not ok" if not_ok else "all sensors ok",
                          not_ok=not_ok, frames=self.published)
        else:
            self.diag.update_values("sensors", frames=self.published)

    # -- stamps ---------------------------------------------------------------------------
    def _stamp_check(self, stream: str, t: float, clock_s: float | None) -> StampCheck:
        """Whether ``t`` on ``stream`` is on the graph's clock ``clock_s`` (a refusal is counted, said once)."""
        check, refresh = admit(self.stamps[stream], t, clock_s, self.get_logger().warning)
        if refresh:
            self._stamp_status()
        return check

    def _stamp_status(self) -> None:
        if self.stamps:
            level, text, values = stamp_status(self.stamps.values())
            self.diag.set("stamps", level, text, **values)

    # -- twin -----------------------------------------------------------------------------
    def _on_twin(self, msg: TemperatureArray) -> None:
        t = stamp_to_s(msg.header.stamp)
        check = self._stamp_check("twin", t, graph_clock_s(self.get_clock().now().nanoseconds))
        if not check.accepted:
            if check.refusal is Refusal.BEHIND:
                self._ack(t)     # a late instant: never published, acknowledged so the lock-step goes on
            return   # ahead or not finite: never published, never acknowledged (a forged stamp moves nothing)
        if t <= self._last_twin_t:
            # machine_sim re-sent an instant because an acknowledgement is missing: a consumer
            # may have restarted and missed it (the model after a crash), so the last frame
            # goes out again unchanged (same stamp, same values) when it is this instant; an
            # older instant is only acknowledged. Consumers treat a repeated stamp idempotently.
            if t == self._last_twin_t and self._last_msg is not None:
                self.pub.publish(self._last_msg)
                self.republished += 1
            self._ack(t)
            return
        self._last_twin_t = t
        try:
            self.source.accept(t, list(msg.sensor_ids), list(msg.temperatures_degc), list(msg.status))
        except ValueError as exc:  # a malformed message: every sensor failed for this instant
            self.get_logger().error(str(exc))
            self.source.accept(t, [], [], [])
        if self.period_s <= 0 or t >= self._next_due - 1e-9:
            self._publish(t)
            self._next_due = t + self.period_s
        self._ack(t)  # all work for t_k is done, published or not

    # -- timer-driven (modbus, replay on someone else's clock) ----------------------------
    def _on_timer(self) -> None:
        t = self.get_clock().now().nanoseconds * 1e-9
        self._publish(t)
        self._ack(t)

    # -- replay as the time master --------------------------------------------------------
    def _setup_time_master(self, real_time_factor: float) -> None:
        src: ReplaySource = self.source
        self.steps = src.instants(self.period_s)
        self.k = 0
        self.rtf = real_time_factor
        self.acked = {n: -math.inf for n in self.participants}
        self.clock_pub = self.create_publisher(Clock, "/clock", CLOCK_QOS)
        if self.participants:
            self.create_subscription(SimSync, TOPIC_SIM_SYNC, self._on_sim_sync, SIM_SYNC_QOS)
        self._wall0 = None
        tick = 0.005 if real_time_factor <= 0 else min(0.05, float(np.min(np.diff(self.steps)))
                                                         / real_time_factor if len(self.steps) > 1 else 0.05)
        self.create_timer(max(tick, 0.001), self._advance,
                          clock=RclClock(clock_type=ClockType.STEADY_TIME))  # time master: wall pacing

    def _on_sim_sync(self, msg: SimSync) -> None:
        if msg.node_name in self.acked:
            # the last instant published; before t_0 none, so any acknowledgement of t_0 is ahead
            published = float(self.steps[self.k - 1] if self.k > 0 else self.steps[0] - 1.0)
            if not self._stamp_check("acks", stamp_to_s(msg.processed_until), published).accepted:
                return
            self.acked[msg.node_name] = max(self.acked[msg.node_name], stamp_to_s(msg.processed_until))
            if self.rtf <= 0:
                self._advance()

    def _advance(self) -> None:
        if self.k >= len(self.steps):
            return
        if self.k == 0 and self.participants and (
                self.pub.get_subscription_count() < len(self.participants)
                or self.count_publishers(TOPIC_SIM_SYNC) < len(self.participants)):
            return  # t_0 would be lost: wait until the participants are discovered
        if self.k > 0 and any(v < self.steps[self.k - 1] - 1e-9 for v in self.acked.values()):
            return  # a participant has not finished t_{k-1}
        if self.rtf > 0:
            now = time.monotonic()
            if self._wall0 is None:
                self._wall0 = now
            if now - self._wall0 < (self.steps[self.k] - self.steps[0]) / self.rtf:
                return
        t = float(self.steps[self.k])
        self.clock_pub.publish(Clock(clock=s_to_stamp(t)))
        self._publish(t)
        self._ack(t)
        self.k += 1
        if self.k == len(self.steps):
            self.get_logger().info(f"replay finished at t={t:g} s ({self.k} steps)")

    def close(self) -> None:
        self.source.close()


def main(args=None) -> int:
    return run_node(TemperaturePublisher, args)


if __name__ == "__main__":
    raise SystemExit(main())
