"""StampGuard: stamps ahead of the node's clock, behind the last accepted one or not finite are
refused and counted; a burst is logged once; without a clock only the other tests apply."""
from __future__ import annotations

import math

import pytest

from thermal_comp_common.stamp_guard import (SIM_MAX_AHEAD_S, WALL_MAX_AHEAD_S, Refusal, StampGuard,
                                             default_max_ahead_s, graph_clock_s, stamp_values)


def test_a_stamp_beyond_the_bound_ahead_of_the_clock_is_refused_and_never_becomes_the_last():
    g = StampGuard("temperatures", max_ahead_s=600.0)
    assert g.check(18000.0, clock_now_s=18000.0).accepted
    assert g.check(18300.0, clock_now_s=18000.0).accepted          # one step before its /clock
    forged = g.check(18000.0 + 1e7, clock_now_s=18300.0)
    assert forged.refusal is Refusal.AHEAD and forged.log
    assert "temperatures" in forged.text and "ahead of the node's clock" in forged.text
    assert g.last_accepted_s == 18300.0
    assert g.check(18600.0, clock_now_s=18600.0).accepted          # the next honest instant
    assert g.check(18900.0 + 600.0, clock_now_s=18900.0).accepted  # exactly at the bound
    assert g.counts == {Refusal.AHEAD: 1, Refusal.BEHIND: 0, Refusal.NON_FINITE: 0}


def test_behind_the_last_accepted_is_refused_an_equal_stamp_is_a_resent_instant():
    g = StampGuard("machine_state", max_ahead_s=60.0)
    assert g.check(300.0, None).accepted
    assert g.check(300.0, None).accepted
    late = g.check(0.0, None)
    assert late.refusal is Refusal.BEHIND and "behind the last accepted stamp 300.000 s" in late.text
    free = StampGuard("offsets", max_ahead_s=60.0, forward_only=False)
    assert free.check(300.0, None).accepted and free.check(0.0, None).accepted
    assert free.last_accepted_s == 300.0


@pytest.mark.parametrize("stamp", [math.nan, math.inf, -math.inf])
def test_a_non_finite_stamp_is_refused_with_or_without_a_clock(stamp):
    for clock in (None, 100.0):
        g = StampGuard("errors/predicted", max_ahead_s=60.0)
        check = g.check(stamp, clock)
        assert check.refusal is Refusal.NON_FINITE and g.counts[Refusal.NON_FINITE] == 1
        assert g.last_accepted_s is None


def test_without_a_clock_the_ahead_test_is_skipped():
    g = StampGuard("temperatures", max_ahead_s=60.0)
    assert g.check(1e7, None).accepted
    assert g.check(1e7 + 1e6, 0.0).refusal is Refusal.AHEAD     # a clock at 0 is a clock here
    assert graph_clock_s(0) is None and graph_clock_s(1_500_000_000) == 1.5


def test_a_burst_is_logged_once_and_ends_after_quiet_acceptances():
    g = StampGuard("temperatures", max_ahead_s=60.0, quiet=3)
    checks = [g.check(1e7, 0.0) for _ in range(5)]
    assert [c.log for c in checks] == [True, False, False, False, False] and g.in_burst
    assert g.refused == 5 and g.counts[Refusal.AHEAD] == 5
    ok = [g.check(float(t), float(t)) for t in range(3)]
    assert [c.burst_over for c in ok] == [False, False, True] and not g.in_burst
    interleaved = [g.check(1e7, 10.0).log, g.check(10.0, 10.0).log, g.check(1e7, 10.0).log]
    assert interleaved == [True, False, False]        # one accepted stamp does not end a burst
    assert g.check(-1.0, 10.0).refusal is Refusal.BEHIND and g.refused == 8


def test_the_diagnostics_values_count_every_guard_and_name_the_newest_refusal():
    a, b = StampGuard("temperatures", 60.0), StampGuard("offsets", 60.0)
    assert stamp_values([a, b]) == {"stamps_refused_ahead": 0, "stamps_refused_behind": 0,
                                    "stamps_refused_non_finite": 0, "last_stamp_refused": "none"}
    b.check(1e7, 0.0)
    a.check(math.nan, 0.0)
    v = stamp_values([b, a])
    assert (v["stamps_refused_ahead"], v["stamps_refused_non_finite"]) == (1, 1)
    assert v["last_stamp_refused"].startswith("temperatures: message stamped nan s refused")


def test_the_bound_defaults_follow_the_clock_and_bad_settings_are_refused():
    assert default_max_ahead_s(0.0, sim_time=True) == SIM_MAX_AHEAD_S
    assert default_max_ahead_s(0.0, sim_time=False) == WALL_MAX_AHEAD_S
    assert default_max_ahead_s(5.0, sim_time=True) == 5.0
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="max_ahead_s"):
            StampGuard("x", bad)
    with pytest.raises(ValueError, match="quiet"):
        StampGuard("x", 1.0, quiet=0)
