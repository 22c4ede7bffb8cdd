"""The talc_model node on simulated time refuses a message stamped 10^7 s ahead of its clock:
the model's clock, its acknowledgements and its saved state never see it, the next honest
instant is modelled, the refusal is counted on /diagnostics and logged once per burst."""
from __future__ import annotations

import json

import pytest

from talc_model.state_files import saved_time_s

pytestmark = [pytest.mark.ros]
CONFIG = {"component_names": ["E_X0C"], "input_names": ["a", "b"], "model_step_s": 300.0}
T0 = 18000.0
FORGED = T0 + 1e7


@pytest.fixture
def sim_node(tmp_path, ros_domain_id):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp_testing.sim_clock import SimClock

    from talc_model.talc_model_node import TalcModelNode

    cfg = tmp_path / "talc.yaml"
    cfg.write_text(json.dumps(CONFIG))
    state = tmp_path / "model.json"
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", f"model_config:={cfg}", "-p", f"state_path:={state}",
                                  "-p", "lockstep_participant:=true", "-p", "action_server_wait_s:=0.0",
                                  "-p", "use_sim_time:=true"])
    node = TalcModelNode(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    clock = SimClock(ctx, ex, node)
    set_clock = clock.set

    node.acks, node.preds, node.warnings = [], [], []
    node.sync_pub.publish = lambda msg: node.acks.append(msg.processed_until.sec)
    node.pred_pub.publish = lambda msg: node.preds.append(msg.header.stamp.sec)
    node.get_logger().warning = lambda text, **kw: node.warnings.append(text)
    node.loop.model.probe_due = lambda t: False      # no probing cycles here
    yield node, state, set_clock
    ex.shutdown()
    clock.destroy()
    node.destroy_node()
    ctx.try_shutdown()


def _temps(t):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray
    return TemperatureArray(header=Header(stamp=s_to_stamp(t)), sensor_ids=["a", "b"],
                            temperatures_degc=[20.0 + t / 1e5, 21.0], status=[0, 0])


def _state(t):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import MachineState
    return MachineState(header=Header(stamp=s_to_stamp(t)))


def _offsets(t):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import AxisOffsets
    return AxisOffsets(header=Header(stamp=s_to_stamp(t)), axis_names=["E_X0C"], commanded_offsets_um=[1.0],
                       applied_offsets_um=[1.0], applied=[True], limits_hit=[0], compensation_enabled=True)


def _stamps_status(node):
    s = next(s for s in node.diag.statuses() if s.name.endswith(": stamps"))
    return s, {kv.key: kv.value for kv in s.values}


def test_a_forged_stamp_far_ahead_never_moves_the_model_and_the_next_instant_is_modelled(sim_node):
    node, state, set_clock = sim_node
    set_clock(T0)
    node._on_temperatures(_temps(T0))
    assert node.loop.t_last == T0 and node.acks == [int(T0)] and node.preds == [int(T0)]
    # the attack: one TemperatureArray (and its machine state, offsets) stamped 10^7 s ahead
    node._on_machine_state(_state(FORGED))
    node._on_temperatures(_temps(FORGED))
    node._on_offsets(_offsets(FORGED))
    node._on_temperatures(_temps(FORGED))
    assert node.loop.t_last == T0 and node.acks == [int(T0)] and node.preds == [int(T0)]
    assert node.instant_inputs.state_t == -float("inf") and node.sink.stamp_s < T0
    # one line per topic for the burst: the second forged temperatures are counted, not logged
    assert [w.split(":")[0] for w in node.warnings] == ["machine_state", "temperatures", "offsets"]
    assert all("ahead of the node's clock" in w for w in node.warnings)
    status, values = _stamps_status(node)
    assert status.level == b"\x01" and values["stamps_refused_ahead"] == "4"
    # the next honest instant (its /clock first) is modelled and acknowledged
    set_clock(T0 + 300.0)
    node._on_machine_state(_state(T0 + 300.0))
    node._on_temperatures(_temps(T0 + 300.0))
    assert node.loop.t_last == T0 + 300.0 and node.acks == [int(T0), int(T0 + 300.0)]
    node.close()                                         # shutdown save: the model's own time
    assert saved_time_s(state, node.model) == T0 + 300.0
    assert json.loads(state.read_text())["extra"]["model_time_s"] == T0 + 300.0


def test_a_stamp_behind_the_last_instant_is_refused_without_an_ack(sim_node):
    node, _, set_clock = sim_node
    set_clock(T0 + 300.0)
    node._on_temperatures(_temps(T0 + 300.0))
    node._on_temperatures(_temps(T0))
    assert node.loop.t_last == T0 + 300.0 and node.acks == [int(T0 + 300.0)]
    assert "behind the last accepted stamp" in node.warnings[0]
    assert _stamps_status(node)[1]["stamps_refused_behind"] == "1"
