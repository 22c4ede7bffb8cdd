"""The lock-step roster: acknowledgements ahead of the graph are refused and counted, a participant
gone from the graph is suspended after the bound and re-admitted when it is back (ROS-free)."""
from __future__ import annotations

import math

import pytest

from thermal_comp_common.stamp_guard import Refusal
from thermal_twin.sim.lockstep_roster import LockstepRoster


def test_ack_ahead_of_the_published_instant_is_refused_and_counted():
    r = LockstepRoster(["model", "bridge"], gone_after_s=5.0)
    first = r.ack("model", 1.0e7, published_t=600.0)
    assert first.refusal is Refusal.AHEAD and first.log and "10000000.0" in first.text
    again = r.ack("model", 2.0e7, published_t=600.0)
    assert not again.accepted and not again.log          # the same burst: counted, not logged
    assert r.ack_guard.refused == 2 and "model" not in r.acks
    assert not r.all_acked(600.0)
    assert r.ack("model", 600.0, 600.0).accepted and r.ack("bridge", 600.0, 600.0).accepted
    assert r.all_acked(600.0)


def test_non_finite_ack_is_refused_and_no_participant_is_none():
    r = LockstepRoster(["model"], gone_after_s=5.0)
    assert r.ack("model", math.nan, 0.0).refusal is Refusal.NON_FINITE
    assert r.ack("somebody_else", 1e9, 0.0) is None     # not a participant: not a verdict at all
    assert r.ack_guard.refused == 1


def test_an_older_ack_after_a_newer_one_is_accepted_and_never_lowers():
    r = LockstepRoster(["model"], gone_after_s=5.0)
    assert r.ack("model", 120.0, 120.0).accepted
    assert r.ack("model", 60.0, 120.0).accepted          # a re-acknowledged older instant
    assert r.acks["model"] == 120.0


def test_gone_participant_is_suspended_after_the_bound_and_readmitted():
    r = LockstepRoster(["model", "bridge"], gone_after_s=5.0)
    r.ack("model", 60.0, 60.0)
    assert r.observe({"model", "bridge"}, wall_s=0.0) == ([], [])
    assert r.observe({"model"}, wall_s=10.0) == ([], [])            # missing since 10 s
    assert r.observe({"model"}, wall_s=14.9) == ([], [])
    assert not r.all_acked(60.0)
    assert r.observe({"model"}, wall_s=15.0) == (["bridge"], [])
    assert r.active == ["model"] and r.all_acked(60.0)             # the graph goes on without it
    assert r.observe({"model"}, wall_s=30.0) == ([], [])            # said once
    assert r.observe({"model", "bridge"}, wall_s=31.0) == ([], ["bridge"])
    assert r.active == ["model", "bridge"] and r.unacked(60.0) == ["bridge"]


def test_a_short_absence_is_forgotten():
    r = LockstepRoster(["bridge"], gone_after_s=5.0)
    r.observe(set(), wall_s=0.0)
    r.observe({"bridge"}, wall_s=4.0)
    assert r.missing_for("bridge", 4.0) == 0.0
    assert r.observe(set(), wall_s=6.0) == ([], [])                  # a new absence starts at 6 s
    assert r.observe(set(), wall_s=11.0) == (["bridge"], [])


def test_drop_removes_for_good():
    r = LockstepRoster(["model", "viewer"], gone_after_s=5.0)
    r.observe({"model"}, 0.0)
    r.observe({"model"}, 5.0)
    r.drop(["viewer"])
    assert r.participants == ["model"] and not r.suspended
    assert r.observe({"model", "viewer"}, 6.0) == ([], [])


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_bound_is_validated(bad):
    with pytest.raises(ValueError, match="participant_gone_s"):
        LockstepRoster(["model"], gone_after_s=bad)
