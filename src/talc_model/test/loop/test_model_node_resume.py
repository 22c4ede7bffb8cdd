"""The talc_model node refuses a resumed state saved after the graph's first instant: one
error naming the file and both times, the file kept aside, a fresh model, the instant acked."""
from __future__ import annotations

import json

import pytest

from talc_model.adaptive_model import make_model
from talc_model.model_persistence import save_model

pytestmark = [pytest.mark.ros]
CONFIG = {"component_names": ["E_X0C"], "input_names": ["a", "b"], "model_step_s": 300.0}


@pytest.fixture
def node_with_state(tmp_path, ros_domain_id):
    import rclpy
    from talc_model.talc_model_node import TalcModelNode

    cfg = tmp_path / "talc.yaml"
    cfg.write_text(json.dumps(CONFIG))            # JSON is YAML
    state = tmp_path / "state" / "model.json"
    model = make_model("talc", CONFIG)
    for k in range(3):
        model.update_inputs(37320.0 + 300.0 * k, {"a": 20.0, "b": 21.0}, {})
    save_model(state, model, extra={"model_time_s": 37920.0})
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", f"model_config:={cfg}", "-p", f"state_path:={state}",
                                  "-p", "lockstep_participant:=true", "-p", "action_server_wait_s:=0.0"])
    node = TalcModelNode(context=ctx)
    yield node, state
    node.destroy_node()
    ctx.try_shutdown()


def test_a_state_from_a_later_time_is_refused_moved_aside_and_the_instant_goes_on(node_with_state):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import SimSync, TemperatureArray

    node, state = node_with_state
    logged, acks = [], []
    node.get_logger().error = lambda text, **kw: logged.append(text)
    node.sync_pub.publish = lambda msg: acks.append(msg)
    assert node.loop.resumed.time_s == 37920.0
    msg = TemperatureArray(header=Header(stamp=s_to_stamp(0.0)), sensor_ids=["a", "b"],
                           temperatures_degc=[20.0, 21.0],
                           status=[TemperatureArray.STATUS_OK, TemperatureArray.STATUS_OK])
    node._on_temperatures(msg)
    assert len(logged) == 1
    assert str(state) in logged[0] and "37920.000 s" in logged[0] and "first instant 0.000 s" in logged[0]
    aside = state.with_name("model.refused-t37920.json")
    assert f"moved aside to {aside}" in logged[0] and "starting with a new model" in logged[0]
    assert aside.is_file() and json.loads(aside.read_text())["extra"]["model_time_s"] == 37920.0
    assert node.model.status(0.0).phase == "calibration" and node.loop.t_last == 0.0
    assert [a.processed_until.sec for a in acks if isinstance(a, SimSync)] == [0]   # never stuck at t=0
    node._on_temperatures(TemperatureArray(header=Header(stamp=s_to_stamp(300.0)), sensor_ids=["a", "b"],
                                           temperatures_degc=[20.5, 21.0], status=[0, 0]))
    assert len(logged) == 1 and [a.processed_until.sec for a in acks] == [0, 300]
