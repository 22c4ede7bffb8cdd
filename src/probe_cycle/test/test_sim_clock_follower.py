"""probe_cycle's simulated time comes through a private single-threaded node, not through a
``/clock`` subscription in its MultiThreadedExecutor (which spun a core and delayed the
touch-probe client: sim_clock_follower.py says what was measured). use_sim_time stays applied:
the host node's clock follows ``/clock`` while the host is never spun, and a later change of
use_sim_time is refused, not accepted and ignored."""
from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

from probe_cycle.sim_clock_follower import SimClockFollower  # noqa: E402
from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, s_to_stamp  # noqa: E402


@pytest.mark.ros
def test_the_host_clock_follows_clock_without_its_own_subscription(ros_context):
    host = rclpy.create_node("probe_cycle", namespace="/sim_clock_follower", context=ros_context,
                             parameter_overrides=[Parameter("use_sim_time", value=True)])
    follower = SimClockFollower(host)
    sim = rclpy.create_node("machine_sim", context=ros_context)
    pub = sim.create_publisher(Clock, "/clock", SENSOR_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(sim)
    try:
        assert not [s for s in host.subscriptions if s.topic_name == "/clock"]
        end = time.monotonic() + 60.0
        while pub.get_subscription_count() == 0:
            assert time.monotonic() < end, "the follower never subscribed to /clock"
            ex.spin_once(timeout_sec=0.05)
        for t_s in (123.0, 456.5):
            while host.get_clock().now().nanoseconds != int(t_s * 1e9):
                assert time.monotonic() < end, f"host clock {host.get_clock().now()} never reached {t_s}"
                pub.publish(Clock(clock=s_to_stamp(t_s)))
                ex.spin_once(timeout_sec=0.05)
        result = host.set_parameters([Parameter("use_sim_time", value=False)])[0]
        assert not result.successful and "start-up only" in result.reason
        assert host.get_parameter("use_sim_time").value is True
    finally:
        follower.close()
        ex.shutdown()
        sim.destroy_node()
        host.destroy_node()
