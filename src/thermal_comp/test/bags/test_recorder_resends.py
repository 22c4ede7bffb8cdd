"""The recorder writes a re-sent instant once (each topic holds each instant once) and still
acknowledges the copy; a changed message at the same stamp is written; ``keep_resends`` writes
every copy. In-process: a publisher node and the recorder in one context, one executor; the
test spins until the recorder's counters reach what was sent (bounded), no sleeps."""
from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

pytestmark = pytest.mark.ros


def _record(tmp_path, keep_resends: bool):
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp.bags.recorder_node import BagRecorderNode
    from thermal_comp_common.runtime import node_runtime as rt
    from thermal_comp_msgs.msg import MachineState, ModelStatus, SimSync, TemperatureArray, ThermalErrors
    ns = f"/resend_{str(keep_resends).lower()}"
    out = tmp_path / f"bag_{keep_resends}"
    ctx = rclpy.context.Context()
    rclpy.init(args=["rec", "--ros-args", "-r", f"__ns:={ns}", "-p", f"output:={out}",
                     "-p", "lockstep_participant:=true", "-p", f"keep_resends:={str(keep_resends).lower()}"],
               context=ctx)
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

    def instant(t_s: float, phase: int):
        msgs = {rt.TOPIC_MACHINE_STATE: MachineState(spindle_speed_rpm=1000.0 + t_s),
                rt.TOPIC_TWIN_SENSORS: TemperatureArray(sensor_ids=["a"], temperatures_degc=[20.0 + t_s],
                                                        status=[0]),
                rt.TOPIC_ERRORS_TRUE: ThermalErrors(component_names=["E_X0C"], values=[t_s]),
                rt.TOPIC_MODEL_STATUS: ModelStatus(phase=phase)}
        for topic, m in msgs.items():
            m.header.stamp = rt.s_to_stamp(t_s)
            pubs[topic].publish(m)

    def spin_until(messages: int, skipped: int, n_acks: int):
        while (rec.writer.message_count, rec.resends_skipped, len(acks)) != (messages, skipped, n_acks):
            assert time.monotonic() < end, (rec.writer.message_count, rec.resends_skipped, len(acks))
            ex.spin_once(timeout_sec=0.05)

    instant(0.0, 0)
    spin_until(4, 0, 1)
    instant(0.0, 0)          # machine_sim re-sends t = 0, everyone repeats
    spin_until(8 if keep_resends else 4, 0 if keep_resends else 4, 2)
    instant(0.0, 1)         # the same instant, the model's status changed: written
    spin_until(12 if keep_resends else 5, 0 if keep_resends else 7, 3)
    instant(300.0, 1)
    spin_until(16 if keep_resends else 9, 0 if keep_resends else 7, 4)
    rec.close()
    ex.shutdown()
    rec.destroy_node()
    src.destroy_node()
    ctx.try_shutdown()
    return out, [rt.stamp_to_s(a.processed_until) for a in acks]


@pytest.mark.parametrize("keep", [False, True], ids=["once", "keep_resends"])
def test_a_resent_instant_is_written_once_and_acknowledged_again(tmp_path, keep):
    from collections import Counter
    from thermal_comp_common.bags.reader import read_bag
    out, acks = _record(tmp_path, keep)
    assert acks == [0.0, 0.0, 0.0, 300.0]          # a copy is acknowledged like the first
    bag = read_bag(out)
    counts = Counter(m.topic.rsplit("/", 1)[-1] for m in bag.messages)
    for topic in ("machine_state", "sensor_readings", "ground_truth"):   # t = 0 sent 3 times, 300 s once
        assert counts[topic] == (4 if keep else 2), counts
    assert counts["model_status"] == (4 if keep else 3), counts   # two contents at t = 0, one at 300 s
