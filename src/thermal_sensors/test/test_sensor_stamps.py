"""The sensors node validates the time of what it receives: twin readings stamped far ahead of its
clock or not finite are neither published nor acknowledged, one behind the last instant is
acknowledged (the lock-step goes on) but not published (one forged
message made every honest instant after it "old": acknowledged, never published again), and as
the time master it ignores an acknowledgement of an instant it has not published. Each refusal is
counted on /diagnostics and logged once per burst. In-process, on simulated time."""
from __future__ import annotations

import math

import pytest

from sensor_test_data import make_recording

pytestmark = [pytest.mark.ros]
SENSORS = ["ambient", "ws_mwf", "c_coolant_delta", "c_motor_internal"]   # the nmv5000 sensors


def _node(ctx, params: list[str]):
    import rclpy
    from thermal_sensors.temperature_publisher_node import TemperaturePublisher
    rclpy.init(context=ctx, args=["--ros-args", *[x for p in params for x in ("-p", p)]])
    node = TemperaturePublisher(context=ctx)
    node.sent, node.acks, node.warnings = [], [], []
    node.pub.publish = lambda msg: node.sent.append(msg.header.stamp.sec)
    if node.sync_pub is not None:
        node.sync_pub.publish = lambda msg: node.acks.append(msg.processed_until.sec)
    node.get_logger().warning = lambda text, **kw: node.warnings.append(text)
    return node


def _stamps(node) -> dict[str, str]:
    s = next(s for s in node.diag.statuses() if s.name.endswith(": stamps"))
    return {"level": s.level, **{kv.key: kv.value for kv in s.values}}


@pytest.fixture
def twin_node(ros_domain_id):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp_testing.sim_clock import SimClock
    ctx = rclpy.context.Context()
    node = _node(ctx, ["source:=twin", "sensor_config:=nmv5000", "lockstep_participant:=true",
                       "use_sim_time:=true"])
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    clock = SimClock(ctx, ex, node)
    yield node, clock.set
    ex.shutdown()
    clock.destroy()
    node.destroy_node()
    ctx.try_shutdown()


def _readings(t: float):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray
    return TemperatureArray(header=Header(stamp=s_to_stamp(t)), sensor_ids=SENSORS,
                            temperatures_degc=[20.0, 21.0, 0.5, 30.0], status=[0] * 4)


def test_twin_readings_with_forged_stamps_are_neither_published_nor_acknowledged(twin_node):
    node, set_clock = twin_node
    set_clock(600.0)
    node._on_twin(_readings(600.0))
    assert node.sent == [600] and node.acks == [600]
    node._on_twin(_readings(600.0 + 1e7))            # the attack
    node._on_twin(_readings(600.0 + 2e7))
    assert node.sent == [600] and node.acks == [600]
    assert len(node.warnings) == 1 and "ahead of the node's clock" in node.warnings[0]
    set_clock(900.0)
    node._on_twin(_readings(900.0))                  # the next honest instant goes out
    assert node.sent == [600, 900] and node.acks == [600, 900]
    node._on_twin(_readings(300.0))                  # behind the last instant: acknowledged, not published
    assert node.sent == [600, 900] and node.acks == [600, 900, 300]
    values = _stamps(node)
    assert values["level"] == b"\x01" and values["stamps_refused_ahead"] == "2"
    assert values["stamps_refused_behind"] == "1"


def test_twin_re_sent_instant_is_still_republished(twin_node):
    node, set_clock = twin_node
    set_clock(600.0)
    node._on_twin(_readings(600.0))
    node._on_twin(_readings(600.0))                  # machine_sim's re-send: same stamp passes
    assert node.sent == [600, 600] and node.acks == [600, 600] and node.republished == 1
    assert _stamps(node)["stamps_refused_behind"] == "0"


def test_time_master_ignores_an_acknowledgement_of_an_instant_not_published(tmp_path, ros_domain_id):
    import rclpy
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import SimSync
    csv = tmp_path / "rec.csv"
    t, _ = make_recording(csv, n_rows=5, dt_s=10.0)
    ctx = rclpy.context.Context()
    node = _node(ctx, ["source:=replay", f"csv_path:={csv}", "time_master:=true",
                       "lockstep_participants:=['model']"])
    try:
        def ack(t_s):
            node._on_sim_sync(SimSync(header=Header(stamp=s_to_stamp(t_s)), node_name="model",
                                      processed_until=s_to_stamp(t_s)))
        ack(float(t[0]))                               # before t_0 went out: ahead
        assert node.acked["model"] == -math.inf
        node.count_publishers = lambda topic: 1        # the participant is discovered
        node.pub.get_subscription_count = lambda: 1
        node._advance()
        assert node.sent == [int(t[0])]
        ack(1.0e7)                                     # forged, far ahead
        assert node.acked["model"] == -math.inf and node.k == 1
        ack(float(t[0]))
        assert node.acked["model"] == float(t[0])
        values = _stamps(node)
        assert values["stamps_refused_ahead"] == "2" and len(node.warnings) == 1
    finally:
        node.destroy_node()
        ctx.try_shutdown()
