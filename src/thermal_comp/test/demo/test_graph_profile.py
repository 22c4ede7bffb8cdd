"""The lock-step round-trip breakdown of ``bench graph`` (thermal_comp.demo.graph_profile) on
hand-made arrival times."""
import pytest

from thermal_comp.demo.graph_profile import (LATENCY_PARTS, STAGES, ack_breakdown, instant_events,
                                       latency_breakdown, stage_breakdown)

PARTS = ["sensors", "model", "bridge"]


def _run(n: int = 4):
    """Instant k at 100 ms steps: temperatures +1 ms, prediction +3, offsets +13, acks
    sensors +2, model +4, bridge +14 (the last), next instant 20 ms after that ack."""
    arrivals, acks = {}, {}
    for k in range(n):
        s, t0 = k * 300_000_000_000, k * 0.034
        arrivals[("twin/sensor_readings", s)] = t0
        arrivals[("temperatures", s)] = t0 + 0.001
        arrivals[("errors/predicted", s)] = t0 + 0.003
        arrivals[("offsets", s)] = t0 + 0.013
        for node, d in zip(PARTS, (0.002, 0.004, 0.014)):
            acks[(node, s)] = t0 + d
    return arrivals, acks


def test_stages_split_the_cycle():
    arrivals, acks = _run()
    events = instant_events(arrivals, acks, PARTS)
    assert len(events) == 3          # the last instant has no next one
    out = stage_breakdown(events)
    assert [name for name, _, _ in STAGES] + ["instant (sum)"] == list(out)
    medians = [out[name]["median_ms"] for name, _, _ in STAGES]
    assert medians == pytest.approx([1.0, 2.0, 10.0, 1.0, 20.0], abs=1e-6)
    assert out["instant (sum)"]["median_ms"] == pytest.approx(34.0)
    assert sum(out[name]["share_pct"] for name, _, _ in STAGES) == pytest.approx(100.0, abs=0.3)


def test_instant_missing_an_ack_is_left_out():
    arrivals, acks = _run()
    del acks[("model", 300_000_000_000)]
    assert 300_000_000_000 not in instant_events(arrivals, acks, PARTS)


def test_ack_breakdown_names_who_holds_the_graph():
    arrivals, acks = _run()
    out = ack_breakdown(arrivals, acks, PARTS)
    assert out["bridge"]["last_pct"] == 100.0 and out["sensors"]["last_pct"] == 0.0
    assert out["model"]["median_ms"] == pytest.approx(4.0)


def test_no_instants_no_figures():
    assert stage_breakdown({}) == {}


def test_latency_parts_join_the_bridge_profile_by_stamp():
    """Temperatures +1 ms, prediction +3, offsets +13 (see _run); the bridge's callback starts
    1.5 ms after the prediction's publication and spends 8 ms in the CNC call (6 on the loop)."""
    arrivals, _ = _run()
    rows = [{"stamp_ns": k * 300_000_000_000, "received_wall_s": k * 0.034 + 0.0045,
             "transform_ms": 0.1, "envelope_ms": 0.05, "cnc_call_ms": 8.0, "round_trip_ms": 6.0,
             "round_trips": 1 + (k == 2), "publish_ms": 0.2, "audit_ms": 1.5} for k in range(4)]
    rows.append({"stamp_ns": 99, "received_wall_s": 0.0, "cnc_call_ms": 1.0})   # no such instant
    out = latency_breakdown(arrivals, rows)
    med = {name: out[name]["median_ms"] for name, _ in LATENCY_PARTS}
    assert list(med.values()) == pytest.approx([2.0, 1.5, 0.1, 0.05, 8.0, 6.0, 2.0, 0.2], abs=1e-6)
    assert out["latency (sum)"]["median_ms"] == pytest.approx(12.0)
    assert out["audit line (after it)"]["median_ms"] == pytest.approx(1.5)
    assert out["second reads"] == {"count": 1, "of": 4}
    assert latency_breakdown(arrivals, []) == {}


@pytest.mark.ros
def test_the_monitor_times_publications_and_acknowledgements(ros_context):
    """DemoMonitor records each instant's publication times (source timestamps) and the
    temperature -> offsets latency, once per instant even when an instant is re-sent."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from thermal_comp.demo.monitor import DemoMonitor
    from thermal_comp_common.runtime import node_runtime as rt
    from thermal_comp_msgs.msg import AxisOffsets, SimSync, TemperatureArray

    monitor = DemoMonitor("/monitor_test")
    node = rclpy.create_node("source", namespace="/monitor_test", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    temps = node.create_publisher(TemperatureArray, rt.TOPIC_TEMPERATURES, rt.SENSOR_QOS)
    offsets = node.create_publisher(AxisOffsets, rt.TOPIC_OFFSETS, rt.EVENT_QOS)
    sync = node.create_publisher(SimSync, rt.TOPIC_SIM_SYNC, rt.EVENT_QOS)

    def until(cond, what):
        end = time.monotonic() + 30
        while not cond():
            assert time.monotonic() < end, what
            ex.spin_once(timeout_sec=0.05)

    try:
        until(lambda: temps.get_subscription_count() and offsets.get_subscription_count()
              and sync.get_subscription_count(), "the monitor to subscribe")
        stamp = rt.s_to_stamp(300.0)
        t, o = TemperatureArray(), AxisOffsets()
        t.header.stamp = o.header.stamp = stamp
        before = time.time()
        for _ in range(2):                       # the instant re-sent: counted once
            temps.publish(t)
            offsets.publish(o)
        sync.publish(SimSync(node_name="sensors", processed_until=stamp))
        t.header.stamp = o.header.stamp = rt.s_to_stamp(600.0)    # the next instant, in order after
        temps.publish(t)
        offsets.publish(o)
        until(lambda: ("offsets", 600 * 10**9) in monitor.arrivals and ("sensors", 300 * 10**9) in monitor.acks,
              "the monitor to see both instants")
        assert len(monitor.latencies) == 2 and all(0.0 <= x < 1.0 for x in monitor.latencies)
        assert monitor.sim_s == 0.0              # only machine_sim's instants move it
        twin = node.create_publisher(TemperatureArray, rt.TOPIC_TWIN_SENSORS, rt.SENSOR_QOS)
        until(lambda: twin.get_subscription_count(), "the monitor on twin/sensor_readings")
        t.header.stamp = rt.s_to_stamp(900.0)
        twin.publish(t)
        until(lambda: monitor.sim_s == 900.0, "simulated time to reach the twin's instant")
        published = monitor.arrivals[(rt.TOPIC_TEMPERATURES, 300 * 10**9)]
        assert before - 1.0 < published <= time.time()          # the host clock at publication
    finally:
        monitor.close()
        node.destroy_node()
