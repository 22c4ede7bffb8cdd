"""machine_sim's lock-step re-send: every topic of the instant (ground truth included, which a
restarted recorder also needs), and not while a participant is busy probing (the shipped cell
under load re-sent nearly every instant during the model's probing cycles).

In-process, on a simulated wall clock: the node's ``time`` is replaced, its lock-step tick is
called directly, its publishers are replaced by lists. Nothing spins, nothing sleeps.
"""
from __future__ import annotations

import types

import numpy as np
import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)

from thermal_comp_common.runtime.node_runtime import s_to_stamp  # noqa: E402


class _Pub:
    def __init__(self):
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)


@pytest.fixture
def sim(monkeypatch):
    from thermal_twin import machine_sim_node
    clock = types.SimpleNamespace(now=0.0)
    monkeypatch.setattr(machine_sim_node, "time", types.SimpleNamespace(monotonic=lambda: clock.now))
    ctx = rclpy.context.Context()
    rclpy.init(args=["machine_sim", "--ros-args", "-r", "__ns:=/resend_test",
                     "-p", "lockstep_participants:=['model']", "-p", "hours:=0.1",
                     "-p", "resend_after_s:=2.0", "-p", "probe_noise:=false"], context=ctx)
    node = machine_sim_node.MachineSimNode(context=ctx)
    pubs = {name: _Pub() for name in ("pub_clock", "pub_state", "pub_sensors", "pub_truth")}
    for name, pub in pubs.items():
        setattr(node, name, pub)
    node._publish_instant()
    node.started = True
    try:
        yield node, clock, pubs
    finally:
        node.destroy_node()
        ctx.try_shutdown()


def _counts(pubs):
    return {k: len(p.sent) for k, p in pubs.items() if k != "pub_clock"}


def _touch(node):
    from thermal_comp_msgs.srv import TouchProbe
    from thermal_twin.machine.artefact_geometry import DEFAULT_GEOMETRY, nominal_sphere_centre
    c = nominal_sphere_centre(0.0)
    req = TouchProbe.Request(artefact=0, c_axis_deg=0.0, b_axis_deg=0.0,
                             start_mm=list(c + np.array([0.0, 0.0, DEFAULT_GEOMETRY.contact_radius_mm + 5.0])),
                             direction=[0.0, 0.0, -1.0], max_travel_mm=20.0, duration_s=2.0)
    res = node._on_touch_probe(req, TouchProbe.Response())
    assert res.triggered, res.message
    return res


def test_resend_repeats_every_topic_of_the_instant(sim):
    node, clock, pubs = sim
    assert _counts(pubs) == {"pub_state": 1, "pub_sensors": 1, "pub_truth": 1}
    clock.now = 1.9
    node._lockstep_tick()
    assert _counts(pubs) == {"pub_state": 1, "pub_sensors": 1, "pub_truth": 1}   # not yet
    clock.now = 2.1
    node._lockstep_tick()
    assert _counts(pubs) == {"pub_state": 2, "pub_sensors": 2, "pub_truth": 2}
    for p in ("pub_state", "pub_sensors", "pub_truth"):     # the same instant, the same message
        first, again = pubs[p].sent
        assert again is first and again.header.stamp == s_to_stamp(0.0)


def test_no_resend_while_a_participant_probes(sim):
    node, clock, pubs = sim
    for now in (1.5, 3.0, 4.5, 6.0):          # a probing cycle: a touch every 1.5 s of wall time
        clock.now = now
        _touch(node)
        node._lockstep_tick()
    assert _counts(pubs)["pub_state"] == 1, "re-sent although the graph was busy probing"
    clock.now = 8.1                           # 2.1 s after the last touch: quiet, acknowledgement missing
    node._lockstep_tick()
    assert _counts(pubs) == {"pub_state": 2, "pub_sensors": 2, "pub_truth": 2}


def test_acknowledged_instant_advances_without_resend(sim):
    from thermal_comp_msgs.msg import SimSync
    node, clock, pubs = sim
    clock.now = 0.5
    node._on_sync(SimSync(node_name="model", processed_until=s_to_stamp(0.0)))
    assert _counts(pubs) == {"pub_state": 2, "pub_sensors": 2, "pub_truth": 2}
    stamps = [m.header.stamp.sec for m in pubs["pub_truth"].sent]
    assert stamps[0] == 0 and stamps[1] > 0            # the next instant, not a copy
