"""A forged instant stamped far ahead of the recorder's clock is neither recorded nor acknowledged
(a lock-step recorder would otherwise report it processed), is counted on /diagnostics and said
once; honest instants after it are recorded and acknowledged as before. In-process, bounded spins."""
from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

pytestmark = pytest.mark.ros


def test_an_instant_stamped_far_ahead_is_not_recorded_nor_acknowledged(tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp.bags.recorder_node import BagRecorderNode
    from thermal_comp_common.bags.reader import read_bag
    from thermal_comp_common.runtime import node_runtime as rt
    from thermal_comp_msgs.msg import MachineState, ModelStatus, SimSync, TemperatureArray, ThermalErrors
    ns, out = "/stamps_rec", tmp_path / "bag"
    ctx = rclpy.context.Context()
    rclpy.init(args=["rec", "--ros-args", "-r", f"__ns:={ns}", "-p", f"output:={out}",
                     "-p", "lockstep_participant:=true"], context=ctx)
    rec = BagRecorderNode(context=ctx)
    src = rclpy.create_node("source", namespace=ns, context=ctx, use_global_arguments=False)
    acks = []
    src.create_subscription(SimSync, rt.TOPIC_SIM_SYNC, acks.append, rt.EVENT_QOS)
    pubs = {rt.TOPIC_MACHINE_STATE: src.create_publisher(MachineState, rt.TOPIC_MACHINE_STATE, rt.SENSOR_QOS),
            rt.TOPIC_TWIN_SENSORS: src.create_publisher(TemperatureArray, rt.TOPIC_TWIN_SENSORS, rt.SENSOR_QOS),
            rt.TOPIC_ERRORS_TRUE: src.create_publisher(ThermalErrors, rt.TOPIC_ERRORS_TRUE, rt.EVENT_QOS),
            rt.TOPIC_MODEL_STATUS: src.create_publisher(ModelStatus, rt.TOPIC_MODEL_STATUS, rt.LATCHED_QOS)}
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(rec)
    ex.add_node(src)
    end = time.monotonic() + 60.0
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        assert time.monotonic() < end, "the recorder never subscribed"
        ex.spin_once(timeout_sec=0.05)

    def instant(t_s: float):
        msgs = {rt.TOPIC_MACHINE_STATE: MachineState(spindle_speed_rpm=1000.0),
                rt.TOPIC_TWIN_SENSORS: TemperatureArray(sensor_ids=["a"], temperatures_degc=[20.0], status=[0]),
                rt.TOPIC_ERRORS_TRUE: ThermalErrors(component_names=["E_X0C"], values=[1.0]),
                rt.TOPIC_MODEL_STATUS: ModelStatus(phase=0)}
        for topic, m in msgs.items():
            m.header.stamp = rt.s_to_stamp(t_s)
            pubs[topic].publish(m)

    forged = time.time() + 1e7                      # the recorder runs on wall time here
    instant(forged)
    while sum(sum(g.counts.values()) for g in rec.stamps.values()) < 4:
        assert time.monotonic() < end, {t: g.counts for t, g in rec.stamps.items()}
        ex.spin_once(timeout_sec=0.05)
    instant(100.0)
    while len(acks) < 1:
        assert time.monotonic() < end, "the honest instant was never acknowledged"
        ex.spin_once(timeout_sec=0.05)
    assert rec.writer.message_count == 4 and rec.acked_ns == 100 * 10**9
    rec.close()
    ex.shutdown()
    rec.destroy_node()
    src.destroy_node()
    ctx.try_shutdown()
    assert [rt.stamp_to_s(a.processed_until) for a in acks] == [100.0]
    assert len(read_bag(out).messages) == 4          # the honest instant only
