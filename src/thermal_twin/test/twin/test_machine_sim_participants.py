"""machine_sim and participants that misbehave: a participant gone from the graph does not hold it
(suspended after ``participant_gone_s``, re-admitted when back), an acknowledgement of an instant
never published and offsets stamped ahead are ignored and counted, a touch waits for missing offsets
once per instant.

In-process, on a simulated wall clock (the node's ``time`` is replaced, its lock-step tick called
directly, its publishers replaced by lists). The participants are real nodes of the same process:
their presence is the graph's, which is waited for (bounded) before the simulated clock moves.
"""
from __future__ import annotations

import time
import types

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, TOPIC_OFFSETS, TOPIC_SIM_SYNC,  # noqa: E402
                                                      s_to_stamp)
from thermal_comp_msgs.msg import AxisOffsets, SimSync  # noqa: E402
from test_machine_sim_resend import _Pub, _counts, _touch

NS = "/participants_test"
GONE_S = 3.0   # the test's bound (the default is 10 s)


class _Clock:
    """The node's ``time``: a simulated monotonic clock; ``sleep`` advances it."""

    def __init__(self):
        self.now = 0.0
        self.sleeps = 0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.sleeps += 1
        self.now += max(s, 0.01)


class _Log:
    def __init__(self):
        self.lines = []

    def __getattr__(self, level):
        return lambda text, **_: self.lines.append((level, text))


@pytest.fixture
def sim(monkeypatch, ros_domain_id):
    from thermal_twin import machine_sim_node
    clock = _Clock()
    monkeypatch.setattr(machine_sim_node, "time", types.SimpleNamespace(monotonic=clock.monotonic,
                                                                          sleep=clock.sleep))
    ctx = rclpy.context.Context()
    rclpy.init(args=["machine_sim", "--ros-args", "-r", f"__ns:={NS}",
                     "-p", "lockstep_participants:=['model','bridge']", "-p", "hours:=0.1",
                     "-p", f"participant_gone_s:={GONE_S}", "-p", "probe_noise:=false",
                     "-p", "resend_after_s:=600.0"], context=ctx)   # counts below are of new instants
    node = machine_sim_node.MachineSimNode(context=ctx)
    log = _Log()
    node.get_logger = lambda: log
    pubs = {name: _Pub() for name in ("pub_clock", "pub_state", "pub_sensors", "pub_truth")}
    for name, pub in pubs.items():
        setattr(node, name, pub)
    peers = {}

    def join(name):
        peer = rclpy.create_node(name, namespace=NS, context=ctx)
        peer.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
        peers[name] = peer
        _graph_shows(node, name, True)

    def leave(name):
        peers.pop(name).destroy_node()
        _graph_shows(node, name, False)

    join("model")
    join("bridge")
    node._publish_instant()
    node.started = True
    try:
        yield types.SimpleNamespace(node=node, clock=clock, pubs=pubs, log=log, join=join, leave=leave, ctx=ctx)
    finally:
        for peer in peers.values():
            peer.destroy_node()
        node.destroy_node()
        ctx.try_shutdown()


def _graph_shows(node, name: str, present: bool, timeout_s: float = 10.0) -> None:
    """Wait (bounded, on the real clock) until the graph shows ``name`` on sim_sync or not."""
    end = time.monotonic() + timeout_s
    while (name in node._sync_publishers()) != present:
        assert time.monotonic() < end, f"the graph did not show {name} {'joining' if present else 'leaving'}"
        time.sleep(0.01)


def _ack(node, name: str, t: float) -> None:
    node._on_sync(SimSync(node_name=name, processed_until=s_to_stamp(t)))


def _tick_at(s, wall_s: float) -> None:
    s.clock.now = wall_s
    s.node._lockstep_tick()


def test_a_gone_participant_is_gone_on_without_after_the_bound_and_readmitted(sim):
    node, pubs = sim.node, sim.pubs
    t0 = node.published_t
    _ack(node, "model", t0)
    _ack(node, "bridge", t0)
    assert _counts(pubs)["pub_state"] == 2
    t1 = node.published_t
    _ack(node, "model", t1)
    sim.leave("bridge")                       # the bridge dies before it acknowledged t1
    _tick_at(sim, 1.0)                        # missing since 1.0 s
    _tick_at(sim, 1.0 + GONE_S - 0.5)
    assert _counts(pubs)["pub_state"] == 2, "went on before participant_gone_s"
    _tick_at(sim, 1.0 + GONE_S)
    assert _counts(pubs)["pub_state"] == 3 and node.published_t > t1, "a dead participant held the graph"
    gone = [(level, text) for level, text in sim.log.lines if "bridge is gone" in text]
    assert len(gone) == 1 and gone[0][0] == "error" and f"t = {t1:.0f} s" in gone[0][1]
    assert node.diag.level("lock-step") == b"\x01"            # WARN: going on without it
    assert "bridge" in {s.name: s.message for s in node.diag.statuses()}["machine_sim: lock-step"]
    t2 = node.published_t
    _ack(node, "model", t2)                   # the graph advances on the model alone
    assert _counts(pubs)["pub_state"] == 4
    t3 = node.published_t
    sim.join("bridge")                        # restarted
    _tick_at(sim, 10.0)
    assert any("bridge is back" in text for _, text in sim.log.lines)
    _ack(node, "model", t3)
    assert _counts(pubs)["pub_state"] == 4, "went on without the re-admitted bridge's acknowledgement"
    _ack(node, "bridge", t3)
    assert _counts(pubs)["pub_state"] == 5
    assert node.diag.level("lock-step") == b"\x00"


def test_acknowledgement_ahead_of_the_graph_is_ignored_named_and_counted(sim):
    node, pubs = sim.node, sim.pubs
    forger = rclpy.create_node("forger", namespace=NS, context=sim.ctx)
    forger.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
    _graph_shows(node, "forger", True)
    t0 = node.published_t
    for k in range(3):
        _ack(node, "model", 1.0e7 + k)        # three forged acknowledgements, one burst
    assert node.exit_code == 0 and node.context.ok()
    lines = [text for _, text in sim.log.lines if "ignored" in text]
    assert len(lines) == 1 and "'model'" in lines[0] and "forger" in lines[0] and "10000000.0" in lines[0]
    values = {kv.key: kv.value for s in node.diag.statuses() if s.name == "machine_sim: stamps" for kv in s.values}
    assert values["acks_refused"] == "3" and values["stamps_refused_ahead"] == "3"
    _ack(node, "model", t0)
    _ack(node, "bridge", t0)
    assert _counts(pubs)["pub_state"] == 2, "the honest acknowledgements no longer advance the graph"
    forger.destroy_node()


def test_offsets_stamped_ahead_are_refused_and_move_nothing(sim):
    node = sim.node
    msg = AxisOffsets(axis_names=["Z"], commanded_offsets_um=[40.0], applied_offsets_um=[40.0],
                      applied=[True], limits_hit=[0], compensation_enabled=True)
    msg.header.stamp = s_to_stamp(1.0e7)
    node._on_offsets(msg)
    assert node.applied_offsets == {} and node.offsets_stamp_s is None
    assert node.offsets_guard.refused == 1
    msg.header.stamp = s_to_stamp(node.published_t)
    node._on_offsets(msg)
    assert node.applied_offsets == {"Z": 40.0}


def test_touch_waits_for_missing_offsets_once_per_instant(sim):
    node = sim.node
    bridge = rclpy.create_node("offsets_writer", namespace=NS, context=sim.ctx)
    bridge.create_publisher(AxisOffsets, TOPIC_OFFSETS, EVENT_QOS)
    try:
        node.offsets_stamp_s = node.published_t - 60.0     # offsets seen, none yet for this instant
        end = time.monotonic() + 10.0
        while node.count_publishers(node.resolve_topic_name(TOPIC_OFFSETS)) == 0:
            assert time.monotonic() < end
            time.sleep(0.01)
        _touch(node)
        first = sim.clock.sleeps
        assert first > 0 and sim.clock.now >= node.offsets_wait_s       # the bounded wait
        _touch(node)
        _touch(node)
        assert sim.clock.sleeps == first, "every touch of the instant waited again"
        assert sum("no offsets for this instant" in text for _, text in sim.log.lines) == 1
    finally:
        bridge.destroy_node()


def test_touch_does_not_wait_when_nobody_publishes_offsets(sim):
    node = sim.node
    node.offsets_stamp_s = node.published_t - 60.0
    _touch(node)
    assert sim.clock.sleeps == 0
    assert any("nobody publishes offsets" in text for _, text in sim.log.lines)
