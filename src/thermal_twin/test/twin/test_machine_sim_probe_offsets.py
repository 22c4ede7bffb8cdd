"""machine_sim measures a touch at instant t_k against the offsets the bridge wrote for t_k,
even when the touch request overtakes the offsets message (a loaded machine: the CI figures
of one seed changed from run to run), and waits for them only a bounded time.

In-process: nothing spins the node's executor, so the offsets message waits in the
subscription's queue exactly as when the touch request is served first.
"""
from __future__ import annotations

import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

from thermal_comp_common.runtime.node_runtime import EVENT_QOS, TOPIC_OFFSETS, s_to_stamp  # noqa: E402
from thermal_comp_msgs.msg import AxisOffsets  # noqa: E402
from test_machine_sim_resend import _touch

NS = "/probe_offsets_test"


@pytest.fixture
def sim(request, ros_domain_id):
    from thermal_twin import machine_sim_node
    ctx = rclpy.context.Context()
    rclpy.init(args=["machine_sim", "--ros-args", "-r", f"__ns:={NS}", "-p", "lockstep_participants:=['model']",
                     "-p", "hours:=0.1", "-p", "probe_noise:=false",
                     "-p", f"probe_offsets_wait_s:={request.param}"], context=ctx)
    node = machine_sim_node.MachineSimNode(context=ctx)
    bridge = rclpy.create_node("fake_bridge", namespace=NS, context=ctx)
    pub = bridge.create_publisher(AxisOffsets, TOPIC_OFFSETS, EVENT_QOS)
    node._publish_instant()
    node.started = True
    try:
        yield node, pub
    finally:
        bridge.destroy_node()
        node.destroy_node()
        ctx.try_shutdown()


def _offsets(t_s: float, z_um: float) -> AxisOffsets:
    msg = AxisOffsets(axis_names=["X", "Y", "Z"], commanded_offsets_um=[0.0, 0.0, z_um],
                      applied_offsets_um=[0.0, 0.0, z_um], applied=[True] * 3, limits_hit=[0] * 3,
                      compensation_enabled=True)
    msg.header.stamp = s_to_stamp(t_s)
    return msg


def _touch_z(node) -> float:
    return float(_touch(node).trigger_position_mm[2])


def _next_instant_with_offsets_queued(node, pub, z_um: float) -> float:
    """Instant t0's offsets processed, t1 published, t1's offsets sent but not processed."""
    node._on_offsets(_offsets(node.published_t, 0.0))
    z_before = _touch_z(node)
    node.runner.step()
    node._publish_instant()
    end = time.monotonic() + 10.0
    while pub.get_subscription_count() == 0:       # discovery within one context
        assert time.monotonic() < end, "the offsets subscription never matched"
        time.sleep(0.01)
    pub.publish(_offsets(node.published_t, z_um))
    return z_before


@pytest.mark.parametrize("sim", [10.0], indirect=True)
def test_a_touch_overtaking_its_instants_offsets_measures_against_them(sim):
    node, pub = sim
    z_before = _next_instant_with_offsets_queued(node, pub, 7.0)
    z = _touch_z(node)
    assert node.applied_offsets["Z"] == 7.0 and node.offsets_stamp_s == node.published_t
    # the probe sees the true error minus the compensation: 7 um of Z offset moves the trigger
    assert (z - z_before) * 1000.0 == pytest.approx(-7.0, abs=0.5)


@pytest.mark.parametrize("sim", [0.05], indirect=True)
def test_offsets_that_never_come_are_waited_for_a_bounded_time(sim):
    node, _ = sim
    node._on_offsets(_offsets(node.published_t, 3.0))
    node.runner.step()
    node._publish_instant()                        # the bridge never answers this instant
    _touch_z(node)                                 # returns after 0.05 s, with the old offsets
    assert node.applied_offsets["Z"] == 3.0 and node.offsets_stamp_s < node.published_t
