"""Simulated time for an in-process node under test: a /clock publisher spun with it."""
from __future__ import annotations


class SimClock:
    """A helper node publishing /clock on ``executor``; :meth:`set` spins until ``node`` (with
    ``use_sim_time``) reads the time, an AssertionError after 400 spins."""

    def __init__(self, context, executor, node) -> None:
        # ROS only where a test drives a node: the pytest plugin stays importable without rclpy
        import rclpy
        from rosgraph_msgs.msg import Clock
        from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, s_to_stamp

        self._clock, self._stamp = Clock, s_to_stamp
        self.node, self.executor = node, executor
        self.sim = rclpy.create_node("machine_sim_clock", context=context)
        self.pub = self.sim.create_publisher(Clock, "/clock", SENSOR_QOS)
        executor.add_node(self.sim)

    def set(self, t: float) -> None:
        for _ in range(400):
            if self.node.get_clock().now().nanoseconds == int(t * 1e9):
                return
            self.pub.publish(self._clock(clock=self._stamp(t)))
            self.executor.spin_once(timeout_sec=0.05)
        raise AssertionError(f"the node's clock never reached {t} s")

    def destroy(self) -> None:
        self.sim.destroy_node()
