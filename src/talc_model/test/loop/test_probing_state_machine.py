"""The probing state machine: explicit states, transitions, deadlines, stale events."""
from __future__ import annotations

import math

import pytest

from talc_model.probing.cycle_state import Action, ProbeState, ProbingError, ProbingStateMachine


def test_happy_path_goes_idle_wait_accept_running_idle():
    sm = ProbingStateMachine(offsets_wait_s=2.0, result_wait_s=10.0)
    assert sm.state is ProbeState.IDLE and not sm.busy
    assert sm.request(300.0, now_s=5.0) is Action.SEND_GOAL
    assert sm.state is ProbeState.WAIT_ACCEPT and sm.deadline_s == 15.0
    sm.goal_sent({"E_X0C": 1.5})
    assert sm.accepted(300.0) and sm.state is ProbeState.RUNNING
    out = sm.succeeded(300.0, {"E_X0C": 0.25})
    assert out.success and out.t_s == 300.0
    assert out.measured == {"E_X0C": 0.25} and out.applied == {"E_X0C": 1.5}
    assert sm.state is ProbeState.IDLE and sm.t_s is None and sm.deadline_s == math.inf
    assert (sm.started, sm.failed, sm.timed_out) == (1, 0, 0)


def test_a_failed_or_rejected_cycle_ends_with_its_reason():
    sm = ProbingStateMachine()
    sm.request(0.0, 0.0)
    sm.goal_sent({})
    out = sm.failed_cycle(0.0, "probing goal rejected")
    assert not out.success and out.reason == "probing goal rejected" and out.measured == {}
    assert sm.state is ProbeState.IDLE and sm.failed == 1
    sm.request(600.0, 1.0)
    sm.goal_sent({})
    sm.accepted(600.0)
    out = sm.failed_cycle(None, "aborted by the server")     # None: the current cycle
    assert out.t_s == 600.0 and not out.success and sm.failed == 2


def test_a_timed_out_cycle_is_cancelled_and_its_late_result_is_never_used():
    sm = ProbingStateMachine(result_wait_s=6.0)
    sm.request(900.0, now_s=100.0)
    sm.goal_sent({"E_X0C": 0.0})
    sm.accepted(900.0)
    assert sm.tick(105.9) == (Action.NONE, None)
    action, out = sm.tick(106.0)
    assert action is Action.CANCEL_GOAL
    assert not out.success and "no probing result within 6 s" in out.reason
    assert sm.state is ProbeState.IDLE and sm.timed_out == 1 and sm.failed == 1
    assert sm.succeeded(900.0, {"E_X0C": 3.0}) is None         # stale: ignored
    assert sm.accepted(900.0) is False
    assert sm.failed_cycle(900.0, "late abort") is None
    assert sm.failed == 1


def test_a_probe_while_one_is_running_is_refused():
    sm = ProbingStateMachine()
    sm.request(0.0, 0.0)
    with pytest.raises(ProbingError, match="requested while the cycle at 0 s is wait_accept"):
        sm.request(300.0, 1.0)
    assert sm.t_s == 0.0 and sm.started == 1


def test_waiting_for_offsets_then_they_arrive():
    sm = ProbingStateMachine(offsets_wait_s=2.0, result_wait_s=10.0)
    assert sm.request(600.0, now_s=50.0, wait_for_offsets=True) is Action.NONE
    assert sm.state is ProbeState.WAIT_OFFSETS and sm.deadline_s == 52.0
    assert sm.offsets_arrived(300.0, 50.5) is Action.NONE      # older offsets: keep waiting
    assert sm.offsets_arrived(600.0, 51.0) is Action.SEND_GOAL
    assert sm.state is ProbeState.WAIT_ACCEPT and sm.deadline_s == 61.0
    assert sm.offsets_arrived(900.0, 51.5) is Action.NONE      # only once


def test_offsets_that_never_come_start_the_cycle_at_the_deadline():
    sm = ProbingStateMachine(offsets_wait_s=2.0, result_wait_s=10.0)
    sm.request(600.0, now_s=50.0, wait_for_offsets=True)
    assert sm.tick(51.0) == (Action.NONE, None)
    assert sm.tick(52.0) == (Action.SEND_GOAL, None)
    assert sm.state is ProbeState.WAIT_ACCEPT and sm.deadline_s == 62.0


def test_transitions_out_of_order_and_bad_settings_are_named():
    sm = ProbingStateMachine()
    with pytest.raises(ProbingError, match="goal_sent: the probing cycle is idle, expected wait_accept"):
        sm.goal_sent({})
    sm.request(0.0, 0.0, wait_for_offsets=True)
    with pytest.raises(ProbingError, match="accepted: the probing cycle is wait_offsets"):
        sm.accepted(0.0)
    with pytest.raises(ValueError, match="result_wait_s: -1"):
        ProbingStateMachine(result_wait_s=-1)
    with pytest.raises(ValueError, match="offsets_wait_s: nan"):
        ProbingStateMachine(offsets_wait_s=math.nan)
