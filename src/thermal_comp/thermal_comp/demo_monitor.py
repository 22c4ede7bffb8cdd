"""The demo's in-process watcher of its graph: simulated time for the progress bar, and the
wall-time latency from a temperature message to the offsets answering the same instant."""
from __future__ import annotations

import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rosgraph_msgs.msg import Clock

from thermal_comp_common import node_runtime as rt
from thermal_comp_msgs.msg import AxisOffsets, TemperatureArray


class DemoMonitor:
    """A node in its own context, spun on a daemon thread until :meth:`close`."""

    def __init__(self, namespace: str):
        self.ctx = rclpy.context.Context()
        rclpy.init(args=[], context=self.ctx)
        self.node = rclpy.create_node("demo_monitor", namespace=namespace, context=self.ctx,
                                      start_parameter_services=False)
        self.sim_s = 0.0
        self.temp_wall: dict[int, float] = {}
        self.latencies: list[float] = []
        self.node.create_subscription(Clock, "/clock", self._on_clock, 10)
        self.node.create_subscription(TemperatureArray, rt.TOPIC_TEMPERATURES, self._on_temp, rt.SENSOR_QOS)
        self.node.create_subscription(AxisOffsets, rt.TOPIC_OFFSETS, self._on_offsets, rt.EVENT_QOS)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True, name="demo-monitor")
        self.thread.start()

    @staticmethod
    def _ns(stamp) -> int:
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    def _on_clock(self, msg) -> None:
        self.sim_s = max(self.sim_s, msg.clock.sec + msg.clock.nanosec * 1e-9)

    def _on_temp(self, msg) -> None:
        self.temp_wall.setdefault(self._ns(msg.header.stamp), time.perf_counter())

    def _on_offsets(self, msg) -> None:
        t0 = self.temp_wall.pop(self._ns(msg.header.stamp), None)
        if t0 is not None:
            self.latencies.append(time.perf_counter() - t0)

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
