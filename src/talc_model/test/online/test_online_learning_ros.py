"""The online learner and the model node as ROS nodes on a short run: ``learn_now`` (Trigger)
starts a learning (a stand-in for ``thermal-comp learn`` that adopts), the learner offers the
prior over ``adopt_prior``, the model node warms it over the run's history while instants go on
and swaps it in; the audit has the learner's and the model node's lines."""
import pathlib
import sys
import time

import pytest

from talc_model.online.audit import read_audit
from talc_model.online.prior_swap import prior_digest

FAKE = str(pathlib.Path(__file__).with_name("fake_learn.py"))
STEP = 300.0


def _spin_until(executor, cond, timeout_s=60.0):
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "condition not met within the deadline"
        executor.spin_once(timeout_sec=0.05)


@pytest.mark.ros
@pytest.mark.slow
def test_learn_now_adopt_and_swap_in_a_running_model_node(tmp_path, priors, ros_domain_id):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Header
    from std_srvs.srv import Trigger

    from talc_model.learner_node import LearnerNode
    from talc_model.talc_model_node import TalcModelNode
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray

    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.mcap").write_bytes(b"\x89MCAP0\r\n")
    audit = tmp_path / "audit.jsonl"
    command = f"{sys.executable} {FAKE} --mode adopt --prior {priors['unit_prior']} --config {priors['unit_config']}"
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=[
        "--ros-args", "-p", f"model_config:={priors['run_config']}", "-p", f"prior_path:={priors['type_prior']}",
        "-p", "online_learning:=true", "-p", f"audit_path:={audit}", "-p", "warm_events_per_instant:=20", "-p", "action_server_wait_s:=0.0",
        "-p", f"recording:={bag}", "-p", "twin:=nmv5000", "-p", f"work_dir:={tmp_path / 'learn'}",
        "-p", f"learn_command:={command}", "-p", "poll_period_s:=0.05", "-p", "learn_timeout_s:=60.0"])
    model, learner = TalcModelNode(context=ctx), LearnerNode(context=ctx)
    client_node = rclpy.create_node("client", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    for n in (model, learner, client_node):
        ex.add_node(n)
    rec, k = priors["plant"], 0

    def instant():
        nonlocal k
        model._on_temperatures(TemperatureArray(header=Header(stamp=s_to_stamp(float(rec.time_s[k]))),
                                                sensor_ids=["amb"], status=[0],
                                                temperatures_degc=[float(rec.columns["amb_c"][k])]))
        k += 1
        ex.spin_once(timeout_sec=0.01)
    try:
        first = model.model
        for _ in range(100):
            instant()
        _spin_until(ex, lambda: learner.core.t_s == pytest.approx(99 * STEP))
        cli = client_node.create_client(Trigger, "learn_now")
        assert cli.wait_for_service(timeout_sec=10.0)
        fut = cli.call_async(Trigger.Request())
        _spin_until(ex, fut.done)
        assert fut.result().success, fut.result().message
        _spin_until(ex, lambda: any(ln["event"] == "adoption sent" for ln in read_audit(audit)))
        assert model.model is first                     # warming: the running model goes on
        while model.online.candidate is not None and k < 200:
            instant()
        assert model.model is not first
        lines = read_audit(audit)
        assert [ln["event"] for ln in lines] == ["adoption sent", "swapped"]
        new = prior_digest(priors["unit_prior"])
        assert all(ln["old_prior_sha256"] == prior_digest(priors["type_prior"]) and ln["new_prior_sha256"] == new
                   for ln in lines)
        assert model.online.current_sha256 == new and model.config["type_model"] == priors["unit_cfg"]["type_model"]
        assert lines[1]["model_time_s"] == pytest.approx((k - 1) * STEP)
        instant()                                      # the new model models the next instant
        assert model.loop.t_last == pytest.approx((k - 1) * STEP)
    finally:
        for n in (model, learner, client_node):
            n.destroy_node()
        ctx.try_shutdown()


@pytest.mark.ros
def test_without_online_learning_the_model_node_offers_no_adopt_prior_and_keeps_no_history(priors, ros_domain_id):
    import rclpy

    from talc_model.online.learner import SERVICE_ADOPT_PRIOR
    from talc_model.talc_model_node import TalcModelNode

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", f"model_config:={priors['run_config']}",
                                  "-p", f"prior_path:={priors['type_prior']}", "-p", "action_server_wait_s:=0.0"])
    model = TalcModelNode(context=ctx)
    try:
        assert model.online is None
        names = [srv.srv_name for srv in model.services]    # the node's own services, not the graph's view
        assert not any(n.endswith(SERVICE_ADOPT_PRIOR) for n in names), names
        assert any(n.endswith("get_parameters") for n in names), names     # the listing itself works
    finally:
        model.destroy_node()
        ctx.try_shutdown()
