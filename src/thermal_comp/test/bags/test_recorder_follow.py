"""The recorder's acknowledgement of t_k covers the other participants' outputs of t_k
(``follow_topics``), so the last instant's temperatures and offsets are in the bag before
machine_sim can finish and the graph be stopped (seen under load: the bag lacked the last
instant's ``temperatures`` or ``offsets``). A topic that stops (a bridge switched off) holds
its instant at most ``follow_timeout_s`` and is named; one never published holds nothing.

In-process and deterministic: the twin's topics and the participants' topics come from a test
node in the recorder's context, one executor; the delayed participant is the test publishing its
message later; the test reads the recorder's state after each spin (no sleeps)."""
from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

pytestmark = pytest.mark.ros

S = 1_000_000_000


class Cell:
    """A recorder (lock-step participant) and a test node publishing what the graph would."""

    def __init__(self, tmp_path, name: str, follow_timeout_s: float = 10.0, start: str = ""):
        from rclpy.executors import SingleThreadedExecutor
        from thermal_comp.bags.recorder_node import BagRecorderNode
        from thermal_comp_common.runtime import node_runtime as rt
        from thermal_comp_msgs.msg import AxisOffsets, MachineState, SimSync, TemperatureArray
        ns = f"/follow_{name}"
        self.rt = rt
        self.out = tmp_path / f"bag_{name}"
        self.ctx = rclpy.context.Context()
        rclpy.init(args=["rec", "--ros-args", "-r", f"__ns:={ns}", "-p", f"output:={self.out}",
                         "-p", "lockstep_participant:=true", "-p", f"follow_timeout_s:={follow_timeout_s}",
                         "-p", f"expect_from_start:=['{start}']"],
                   context=self.ctx)
        self.rec = BagRecorderNode(context=self.ctx)
        self.src = rclpy.create_node("bridge", namespace=ns, context=self.ctx, use_global_arguments=False)
        self.acks: list[float] = []
        self.src.create_subscription(SimSync, rt.TOPIC_SIM_SYNC,
                                     lambda m: self.acks.append(rt.stamp_to_s(m.processed_until)), rt.EVENT_QOS)
        self.types = {rt.TOPIC_MACHINE_STATE: (MachineState, rt.SENSOR_QOS),
                      rt.TOPIC_TWIN_SENSORS: (TemperatureArray, rt.SENSOR_QOS),
                      rt.TOPIC_TEMPERATURES: (TemperatureArray, rt.SENSOR_QOS),
                      rt.TOPIC_OFFSETS: (AxisOffsets, rt.EVENT_QOS)}
        self.pubs = {t: self.src.create_publisher(cls, t, q) for t, (cls, q) in self.types.items()}
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.rec)
        self.ex.add_node(self.src)
        self.end = time.monotonic() + 60.0
        self.spin_until(lambda: all(p.get_subscription_count() > 0 for p in self.pubs.values()))

    def spin_until(self, done) -> None:
        while not done():
            assert time.monotonic() < self.end, (self.rec.writer.message_count, self.rec.acked_ns, self.acks)
            self.ex.spin_once(timeout_sec=0.05)

    def publish(self, t_s: float, *topics: str) -> None:
        """Publish ``topics`` stamped t_s and spin until the recorder has written them."""
        n = self.rec.writer.message_count + len(topics)
        for topic in topics:
            msg = self.types[topic][0]()
            msg.header.stamp = self.rt.s_to_stamp(t_s)
            if hasattr(msg, "temperatures_degc"):
                msg.sensor_ids, msg.temperatures_degc, msg.status = ["a"], [20.0 + t_s / 3600], [0]
            self.pubs[topic].publish(msg)
        self.spin_until(lambda: self.rec.writer.message_count == n)

    def twin(self, t_s: float) -> None:
        self.publish(t_s, self.rt.TOPIC_MACHINE_STATE, self.rt.TOPIC_TWIN_SENSORS)

    def close(self):
        self.rec.close()
        self.ex.shutdown()
        self.rec.destroy_node()
        self.src.destroy_node()
        self.ctx.try_shutdown()
        from thermal_comp_common.bags.reader import read_bag
        return {(m.topic.rsplit("/", 1)[-1], m.stamp_ns) for m in read_bag(self.out).messages}


def test_the_last_instant_is_acknowledged_only_once_its_temperatures_and_offsets_are_written(tmp_path):
    c = Cell(tmp_path, "last")
    rt = c.rt
    c.twin(0.0)
    c.publish(0.0, rt.TOPIC_TEMPERATURES, rt.TOPIC_OFFSETS)
    c.spin_until(lambda: c.acks == [0.0])
    # the final instant: the twin's topics are written, the sensors' and the bridge's are still
    # in flight; before, the recorder acknowledged here, machine_sim finished and the graph was
    # stopped before they arrived
    c.twin(300.0)
    assert c.rec.acked_ns == 0
    c.publish(300.0, rt.TOPIC_TEMPERATURES)
    assert c.rec.acked_ns == 0            # the offsets of t = 300 s are still expected
    c.publish(300.0, rt.TOPIC_OFFSETS)    # the delayed participant
    c.spin_until(lambda: c.acks == [0.0, 300.0])
    assert c.rec.follow_dropped == []
    written = c.close()
    assert {("temperatures", 300 * S), ("offsets", 300 * S)} <= written


def test_a_topic_never_published_holds_nothing_and_one_that_stops_is_named_after_the_timeout(tmp_path):
    c = Cell(tmp_path, "stops", follow_timeout_s=0.5)
    rt = c.rt
    c.twin(0.0)                            # no offsets at all (a bridge that is off): t = 0 needs none
    c.publish(0.0, rt.TOPIC_TEMPERATURES)
    c.spin_until(lambda: c.acks == [0.0])
    c.twin(300.0)                          # nor does t = 300 s: it waits for the temperatures only
    c.publish(300.0, rt.TOPIC_TEMPERATURES, rt.TOPIC_OFFSETS)
    c.spin_until(lambda: c.acks == [0.0, 300.0])
    c.twin(600.0)                          # the bridge stops publishing: held, then named and acknowledged
    c.publish(600.0, rt.TOPIC_TEMPERATURES)
    c.spin_until(lambda: c.acks == [0.0, 300.0, 600.0])
    assert c.rec.follow_dropped == [(f"/follow_stops/{rt.TOPIC_OFFSETS}", 600 * S)]
    from thermal_comp_common.runtime.diagnostics import WARN
    assert c.rec.diag.level("recorder") == WARN
    c.twin(900.0)                          # no longer expected: acknowledged without waiting
    c.publish(900.0, rt.TOPIC_TEMPERATURES)
    c.spin_until(lambda: c.acks == [0.0, 300.0, 600.0, 900.0])
    assert len(c.rec.follow_dropped) == 1
    written = c.close()
    assert ("offsets", 600 * S) not in written and ("temperatures", 900 * S) in written


def test_expect_from_start_holds_the_first_instant_until_its_offsets_are_written(tmp_path):
    """Seen under load: the first instant's offsets missing (published by a bridge the recorder
    had not matched yet); the demo cell expects them from the start, machine_sim's re-send of
    t_0 brings them again."""
    c = Cell(tmp_path, "start", start="offsets")
    rt = c.rt
    c.twin(0.0)
    c.publish(0.0, rt.TOPIC_TEMPERATURES)
    assert c.rec.acked_ns is None         # without expect_from_start t = 0 is acknowledged here
    c.publish(0.0, rt.TOPIC_OFFSETS)
    c.spin_until(lambda: c.acks == [0.0])
    assert c.rec.follow_dropped == [] and ("offsets", 0) in c.close()


def test_expect_from_start_naming_a_topic_not_recorded_is_one_clear_error(tmp_path):
    from thermal_comp.bags.recorder_node import BagRecorderNode
    ctx = rclpy.context.Context()
    rclpy.init(args=["rec", "--ros-args", "-p", f"output:={tmp_path / 'bag'}",
                     "-p", "lockstep_participant:=true", "-p", "expect_from_start:=['ofsets']"], context=ctx)
    try:
        with pytest.raises(ValueError, match=r"expect_from_start.*ofsets"):
            BagRecorderNode(context=ctx)
    finally:
        ctx.try_shutdown()
