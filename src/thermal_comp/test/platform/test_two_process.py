"""Cross-process communication of our interfaces: pub/sub of TemperatureArray, the ProbeCycle action."""
from __future__ import annotations

import pytest
import rclpy
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger

from ros_helpers import spawn_test_node, spin_until, stop_process
from thermal_comp_common.runtime.node_runtime import ACTION_PROBE_CYCLE, SENSOR_QOS
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import TemperatureArray

pytestmark = [pytest.mark.ros]


@pytest.fixture
def executor(ros_context):
    ex = SingleThreadedExecutor(context=ros_context)
    yield ex
    ex.shutdown()


def test_temperature_array_pub_sub_across_processes(ros_context, executor, ros_domain_id):
    talker = spawn_test_node("temperature_talker", "/pubsub", "-p", "period_s:=0.02",
                             "-p", "sensor_ids:=[ambient,spindle,c_in]")
    try:
        node = rclpy.create_node("pubsub_listener", context=ros_context)
        executor.add_node(node)
        got: list[TemperatureArray] = []
        node.create_subscription(TemperatureArray, "/pubsub/temperatures", got.append, SENSOR_QOS)
        spin_until(executor, lambda: len(got) >= 5, 30.0, "5 TemperatureArray messages from the other process")
        m = got[-1]
        assert list(m.sensor_ids) == ["ambient", "spindle", "c_in"]
        assert all(s == TemperatureArray.STATUS_OK for s in m.status)
        counts = [g.temperatures_degc[0] - 20.0 for g in got]
        assert counts == sorted(counts), "messages arrived out of order"
        assert m.temperatures_degc[1] - m.temperatures_degc[0] == pytest.approx(0.5)
        assert m.header.stamp.sec > 0
    finally:
        out = stop_process(talker)
    assert talker.returncode == 0, f"talker did not exit cleanly ({talker.returncode}):\n{out}"


def test_probe_cycle_action_goal_feedback_result_cancel(ros_context, executor):
    server = spawn_test_node("probe_action_server", "/action_test")
    try:
        node = rclpy.create_node("probe_client", context=ros_context)
        executor.add_node(node)
        client = ActionClient(node, ProbeCycle, f"/action_test/{ACTION_PROBE_CYCLE}")
        step = node.create_client(Trigger, "/action_test/scripted_probe_server/next")
        spin_until(executor, lambda: client.server_is_ready() and step.service_is_ready(), 30.0,
                   "the ProbeCycle server in the other process")

        # goal -> feedback per point -> result
        feedback: list[ProbeCycle.Feedback] = []
        goal = ProbeCycle.Goal(artefact=ProbeCycle.Goal.ARTEFACT_SPHERE, points_per_indexing=3, timeout_s=60.0)
        fut = client.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f.feedback))
        spin_until(executor, fut.done, 10.0, "goal acceptance")
        handle = fut.result()
        assert handle.accepted
        for k in range(1, 4):
            call = step.call_async(Trigger.Request())
            spin_until(executor, lambda: call.done() and len(feedback) >= k, 10.0, f"feedback {k}")
        res_fut = handle.get_result_async()
        spin_until(executor, res_fut.done, 10.0, "the result")
        result = res_fut.result().result
        assert [f.points_done for f in feedback] == [1, 2, 3]
        assert all(f.points_total == 3 for f in feedback)
        assert result.success and result.duration_s == 95.0
        assert list(result.errors.component_names) == ["E_X0C", "E_A0C"]
        assert list(result.errors.uncertainties) == [0.2, 1.2]

        # a goal that runs until cancelled
        feedback.clear()
        fut = client.send_goal_async(ProbeCycle.Goal(points_per_indexing=0), feedback_callback=lambda f: feedback.append(f.feedback))
        spin_until(executor, fut.done, 10.0, "second goal acceptance")
        handle = fut.result()
        call = step.call_async(Trigger.Request())
        spin_until(executor, lambda: len(feedback) >= 1, 10.0, "first feedback of the second goal")
        cancel = handle.cancel_goal_async()
        spin_until(executor, cancel.done, 10.0, "the cancel response")
        assert len(cancel.result().goals_canceling) == 1
        res_fut = handle.get_result_async()
        spin_until(executor, res_fut.done, 10.0, "the cancelled result")
        from action_msgs.msg import GoalStatus
        assert res_fut.result().status == GoalStatus.STATUS_CANCELED
        assert res_fut.result().result.success is False
        assert "cancelled after 1 points" in res_fut.result().result.message
    finally:
        out = stop_process(server)
    assert server.returncode == 0, f"server did not exit cleanly ({server.returncode}):\n{out}"
