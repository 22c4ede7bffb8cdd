"""The model node's periodic state save runs off the temperature-to-offsets path: after the
bridge's offsets answering its instant and before the lock-step ack of that instant; at once
without a bridge; at the wall-clock deadline when the bridge is silent; never twice."""
from __future__ import annotations

import json
import math

import pytest

from talc_model.save_schedule import SaveNow, SaveSchedule

CONFIG = {"component_names": ["E_X0C"], "input_names": ["a", "b"], "model_step_s": 300.0}
STEP = 300.0


# ---------------------------------------------------------------- the pure schedule
def test_schedule_defers_until_the_offsets_for_its_instant():
    s = SaveSchedule(period_s=600.0, wait_s=2.0)
    assert s.on_instant(0.0, 10.0, offsets_seen=False, offsets_stamp_s=-math.inf, probing=False) is SaveNow.NOW
    s.saved(0.0)
    assert s.on_instant(300.0, 11.0, True, 0.0, False) is SaveNow.NO            # not due
    assert s.on_instant(600.0, 12.0, True, 300.0, False) is SaveNow.DEFERRED
    assert s.pending and not s.offsets_arrived(300.0) and not s.overdue(13.9)
    assert s.on_instant(600.0, 12.5, True, 300.0, False) is SaveNow.NO          # a re-sent instant
    assert s.offsets_arrived(600.0) and s.overdue(14.0)
    s.saved(600.0)
    assert not s.pending and not s.offsets_arrived(600.0) and not s.overdue(1e9)
    # the offsets for t already in, a probing cycle (saves at its end), wait 0
    assert s.on_instant(1200.0, 20.0, True, 1200.0, False) is SaveNow.NOW
    assert s.on_instant(1800.0, 21.0, True, 1500.0, True) is SaveNow.NO
    assert SaveSchedule(600.0, 0.0).on_instant(0.0, 0.0, True, -1.0, False) is SaveNow.NOW


def test_schedule_refuses_a_bad_period():
    with pytest.raises(ValueError, match="save_period_s"):
        SaveSchedule(math.nan, 2.0)


# ---------------------------------------------------------------- the node, callbacks driven
@pytest.fixture
def node(tmp_path, ros_domain_id):
    import rclpy
    from talc_model.talc_model_node import TalcModelNode

    cfg = tmp_path / "talc.yaml"
    cfg.write_text(json.dumps(CONFIG))
    state = tmp_path / "model.json"
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", f"model_config:={cfg}", "-p", f"state_path:={state}",
                                  "-p", "lockstep_participant:=true", "-p", "action_server_wait_s:=0.0",
                                  "-p", "save_period_s:=600.0", "-p", "offsets_wait_s:=2.0"])
    n = TalcModelNode(context=ctx)
    n.events, n.wall_s, n.warnings = [], 100.0, []
    n._wall_s = lambda: n.wall_s
    n.sync_pub.publish = lambda msg: n.events.append(("ack", msg.processed_until.sec))
    real_save = n._save
    n._save = lambda t: (n.events.append(("save", t)), real_save(t))[1]
    n.get_logger().warning = lambda text, **kw: n.warnings.append(text)
    n.probe_at = set()
    n.loop.model.probe_due = lambda t: t in n.probe_at
    yield n, state
    n.destroy_node()
    ctx.try_shutdown()


def temps(node, t):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray
    node._on_temperatures(TemperatureArray(header=Header(stamp=s_to_stamp(t)), sensor_ids=["a", "b"],
                                           temperatures_degc=[20.0 + t / 1e4, 21.0], status=[0, 0]))


def offsets(node, t):
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import AxisOffsets
    node._on_offsets(AxisOffsets(header=Header(stamp=s_to_stamp(t)), axis_names=["E_X0C"],
                                 commanded_offsets_um=[1.0], applied_offsets_um=[1.0], applied=[True],
                                 limits_hit=[0], compensation_enabled=True))


def answered(node, *times):
    """Instants each answered by the bridge's offsets (the bridge is in the graph)."""
    for t in times:
        temps(node, t)
        offsets(node, t)


def test_without_a_bridge_the_save_is_at_once(node):
    n, state = node
    for k in range(4):
        temps(n, k * STEP)
    assert n.events == [("save", 0.0), ("ack", 0), ("ack", 300), ("save", 600.0), ("ack", 600), ("ack", 900)]
    assert json.loads(state.read_text())["extra"]["model_time_s"] == 600.0


def test_the_save_waits_for_the_offsets_and_holds_the_ack(node):
    n, state = node
    answered(n, 0.0, 300.0)
    n.events.clear()
    temps(n, 600.0)                 # due: deferred, the ack of 600 withheld
    assert n.events == [] and n.saves.pending
    temps(n, 600.0)                 # machine_sim re-sends the instant: still held, no save
    offsets(n, 300.0)               # a late copy of older offsets: not the answer to 600
    n._on_wall_timer()
    assert n.events == []
    offsets(n, 600.0)
    assert n.events == [("save", 600.0), ("ack", 600)]
    assert json.loads(state.read_text())["extra"]["model_time_s"] == 600.0
    offsets(n, 600.0)               # a repeated answer saves nothing more
    temps(n, 900.0)
    assert n.events == [("save", 600.0), ("ack", 600), ("ack", 900)] and not n.warnings


def test_a_silent_bridge_releases_the_ack_at_the_deadline(node):
    n, _ = node
    answered(n, 0.0)
    n.events.clear()
    temps(n, 300.0)
    temps(n, 600.0)                 # no offsets for 300 or 600
    assert n.events == [("ack", 300)]
    n.wall_s += 1.9
    n._on_wall_timer()
    assert n.events == [("ack", 300)]
    n.wall_s += 0.2
    n._on_wall_timer()
    assert n.events == [("ack", 300), ("save", 600.0), ("ack", 600)]
    assert len(n.warnings) == 1 and "no offsets for t=600 s within 2.0 s" in n.warnings[0]
    offsets(n, 600.0)               # the late answer: nothing saved twice
    n._on_wall_timer()
    assert n.events == [("ack", 300), ("save", 600.0), ("ack", 600)]


def test_a_probing_cycle_at_the_same_instant_saves_once(node):
    n, _ = node
    answered(n, 0.0, 300.0)
    n.events.clear()
    n.probe_at.add(600.0)
    temps(n, 600.0)                 # the cycle waits for the offsets of 600; the save is its own
    assert n.events == [] and n.loop.probing.busy and not n.saves.pending
    offsets(n, 600.0)               # goal sent, no action server: failed cycle -> its save, the ack
    assert n.events == [("save", 600.0), ("ack", 600)]
    answered(n, 900.0)
    assert n.events == [("save", 600.0), ("ack", 600), ("ack", 900)]


def test_shutdown_saves_a_pending_save(node):
    n, state = node
    answered(n, 0.0)
    temps(n, 600.0)
    assert n.saves.pending
    n.close()
    assert not n.saves.pending and json.loads(state.read_text())["extra"]["model_time_s"] == 600.0
