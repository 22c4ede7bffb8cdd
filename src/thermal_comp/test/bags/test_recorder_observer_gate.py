"""An observer recorder (not a lock-step participant) told what to expect from the start holds back
its errors/ground_truth subscription, the one machine_sim's ``wait_for_subscribers`` waits for,
until every expected topic has a matched publisher; at ``observer_wait_s`` it subscribes anyway and
names what it never heard. In-process: the graph is a test node in the recorder's context, one
executor, the state read after each spin (no sleeps)."""
from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

pytestmark = pytest.mark.ros


class Observer:
    def __init__(self, tmp_path, name: str, wait_s: float = 60.0, expect: str = "temperatures"):
        from rclpy.executors import SingleThreadedExecutor
        from thermal_comp.bags.recorder_node import BagRecorderNode
        from thermal_comp_common.runtime import node_runtime as rt
        self.rt, self.ns = rt, f"/gate_{name}"
        self.ctx = rclpy.context.Context()
        rclpy.init(args=["rec", "--ros-args", "-r", f"__ns:={self.ns}", "-r", "__node:=recorder",
                         "-p", f"output:={tmp_path / name}", "-p", f"observer_wait_s:={wait_s}",
                         "-p", f"expect_from_start:=['{expect}']"], context=self.ctx)
        self.rec = BagRecorderNode(context=self.ctx)
        self.sim = rclpy.create_node("machine_sim", namespace=self.ns, context=self.ctx, use_global_arguments=False)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.rec)
        self.ex.add_node(self.sim)
        self.end = time.monotonic() + 60.0

    def recorder_on_truth(self) -> bool:
        """What machine_sim's observer check sees: the recorder subscribed to the ground truth."""
        infos = self.sim.get_subscriptions_info_by_topic(f"{self.ns}/{self.rt.TOPIC_ERRORS_TRUE}")
        return any(i.node_name == "recorder" for i in infos)

    def spin_until(self, done) -> None:
        while not done():
            assert time.monotonic() < self.end, "condition not reached within 60 s"
            self.ex.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.rec.close()
        self.ex.shutdown()
        self.rec.destroy_node()
        self.sim.destroy_node()
        self.ctx.try_shutdown()


def test_the_ground_truth_is_subscribed_only_once_the_expected_topic_has_a_publisher(tmp_path):
    from thermal_comp_msgs.msg import TemperatureArray
    c = Observer(tmp_path, "held")
    try:
        for _ in range(10):                        # a second of the graph without the sensors' writer
            c.ex.spin_once(timeout_sec=0.1)
        assert c.rec.unheard_topics() == [f"{c.ns}/temperatures"]
        assert not c.recorder_on_truth()           # machine_sim would not start yet
        pub = c.sim.create_publisher(TemperatureArray, c.rt.TOPIC_TEMPERATURES, c.rt.SENSOR_QOS)
        c.spin_until(c.recorder_on_truth)
        assert c.rec.unheard_topics() == [] and pub.get_subscription_count() == 1
    finally:
        c.close()


def test_at_the_deadline_it_subscribes_anyway_and_names_the_topic_never_heard(tmp_path):
    c = Observer(tmp_path, "late", wait_s=0.3)
    try:
        c.spin_until(c.recorder_on_truth)
        assert c.rec.unheard_topics() == [f"{c.ns}/temperatures"]      # still nobody publishes it
    finally:
        c.close()


def test_an_expected_topic_that_is_not_recorded_is_one_clear_error(tmp_path):
    from thermal_comp.bags.recorder_node import BagRecorderNode
    ctx = rclpy.context.Context()
    rclpy.init(args=["rec", "--ros-args", "-r", "__ns:=/gate_bad", "-p", f"output:={tmp_path / 'bad'}",
                     "-p", "expect_from_start:=['temperatrues']"], context=ctx)
    try:
        with pytest.raises(ValueError, match=r"expect_from_start.*temperatrues"):
            BagRecorderNode(context=ctx)
        assert not (tmp_path / "bad").exists()     # refused before any bag was made
    finally:
        ctx.try_shutdown()
