"""The demo's in-process watcher of its graph: simulated time reached (progress bar), the
wall-time latency from a temperature message to the offsets answering the same instant, and
the publication time of every instant's messages and acknowledgements (``bench graph``'s
breakdown of the lock-step round trip, thermal_comp.demo.graph_profile).

Times are the DDS source timestamps (the publisher's clock at publication; one host, one
clock), so how late this watcher itself gets a message does not enter the figures. rclpy's
EventsExecutor cannot hand over the message info, so the watcher spins a
SingleThreadedExecutor whatever the graph's nodes use."""
from __future__ import annotations

import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor

from thermal_comp_common.runtime import node_runtime as rt
from thermal_comp_common.bags.writer import stamp_from_cdr
from thermal_comp_msgs.msg import AxisOffsets, SimSync, TemperatureArray, ThermalErrors

#: Topics whose publication time per instant is recorded (raw: only the leading stamp is read).
TIMED_TOPICS = ((rt.TOPIC_TWIN_SENSORS, TemperatureArray, rt.SENSOR_QOS),
                (rt.TOPIC_TEMPERATURES, TemperatureArray, rt.SENSOR_QOS),
                (rt.TOPIC_ERRORS_PREDICTED, ThermalErrors, rt.EVENT_QOS),
                (rt.TOPIC_OFFSETS, AxisOffsets, rt.EVENT_QOS))


class DemoMonitor:
    """A node in its own context, spun on a daemon thread until :meth:`close`."""

    def __init__(self, namespace: str):
        self.ctx = rclpy.context.Context()
        rclpy.init(args=[], context=self.ctx)
        self.node = rclpy.create_node("demo_monitor", namespace=namespace, context=self.ctx,
                                      start_parameter_services=False)
        #: simulated time reached: the newest instant machine_sim published (/clock, which every
        #: touch of a probing cycle moves too, would cost this watcher four times the messages)
        self.sim_s = 0.0
        self.latencies: list[float] = []
        #: (topic, stamp ns) -> first publication (s); (node, stamp ns) -> first acknowledgement
        self.arrivals: dict[tuple[str, int], float] = {}
        self.acks: dict[tuple[str, int], float] = {}
        for topic, cls, qos in TIMED_TOPICS:
            self.node.create_subscription(cls, topic, self._arrival(topic), qos, raw=True)
        self.node.create_subscription(SimSync, rt.TOPIC_SIM_SYNC, self._on_sync, rt.EVENT_QOS)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True, name="demo-monitor")
        self.thread.start()

    def _arrival(self, topic: str):
        def on_message(data: bytes, info: dict) -> None:
            now = info["source_timestamp"] * 1e-9
            stamp = stamp_from_cdr(data)
            if stamp is None:
                return
            if (topic, stamp) in self.arrivals:
                return          # a re-sent instant: the first publication counts
            self.arrivals[(topic, stamp)] = now
            if topic == rt.TOPIC_TWIN_SENSORS:
                self.sim_s = max(self.sim_s, stamp * 1e-9)
            if topic == rt.TOPIC_OFFSETS:
                t0 = self.arrivals.get((rt.TOPIC_TEMPERATURES, stamp))
                if t0 is not None:
                    self.latencies.append(now - t0)
        return on_message

    def _on_sync(self, msg: SimSync, info: dict) -> None:
        stamp = msg.processed_until.sec * 1_000_000_000 + msg.processed_until.nanosec
        self.acks.setdefault((msg.node_name, stamp), info["source_timestamp"] * 1e-9)

    def _spin(self) -> None:
        while not self._stop.is_set() and self.ctx.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        if self.ctx.ok():
            self.ctx.try_shutdown()
