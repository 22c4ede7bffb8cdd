"""The ROS-free closed loop: what is applied, what the probe sees, what the model learns."""
from __future__ import annotations

import math

import pytest

from talc_model.adaptive_model import ModelStatusData
from talc_model.loop.closed_loop import (ClosedLoop, HeldCompensation, ProbeFailed, ResumedState,
                                    ResumedStateMismatch, StepKind)
from talc_model.probing.cycle_state import Action, ProbeState, ProbingStateMachine


class LearnsTotalModel:
    """Predicts the last total error it learned (+ the temperature 'a'); probes when told."""

    kind = "test"
    component_names = ["E_X0C"]

    def __init__(self, probe_at=()):
        self.probe_at = set(probe_at)
        self.total = 0.0
        self.a = 0.0
        self.t_last = -math.inf
        self.learned, self.failed, self.updates = [], [], 0

    def update_inputs(self, t_s, temperatures, machine_state):
        if t_s < self.t_last:
            raise ValueError(f"update_inputs: time {t_s} goes back (last {self.t_last})")
        self.t_last, self.a = t_s, temperatures.get("a", 0.0)
        self.updates += 1

    def predict(self, t_s):
        return {"E_X0C": self.total + self.a}, {"E_X0C": 0.1}

    def probe_due(self, t_s):
        return t_s in self.probe_at

    def add_measurement(self, t_s, measured, applied_compensation):
        if not math.isfinite(measured["E_X0C"]):
            raise ValueError("measured E_X0C is not finite")
        self.learned.append((t_s, measured["E_X0C"], applied_compensation["E_X0C"]))
        self.total = measured["E_X0C"] + applied_compensation["E_X0C"] - self.a

    def add_failed_measurement(self, t_s, reason):
        self.failed.append((t_s, reason))

    def status(self, t_s):
        return ModelStatusData(phase="compensation", probing_cycles=len(self.learned),
                               failed_probing_cycles=len(self.failed))


TRUE = {0.0: 5.0, 300.0: 6.0, 600.0: 7.0}


def plant_probe(t, applied):
    return {"E_X0C": TRUE[t] - applied["E_X0C"]}


def test_the_probe_sees_the_residual_of_the_prediction_just_applied():
    model = LearnsTotalModel(probe_at={300.0})
    sink = HeldCompensation(model.component_names)
    loop = ClosedLoop(model, sink, probe=plant_probe)
    s0 = loop.step(0.0, {"a": 1.0}, {})
    assert s0.kind is StepKind.NEW and s0.values == {"E_X0C": 1.0} and s0.outcome is None
    s1 = loop.step(300.0, {"a": 2.0}, {})
    assert s1.values == {"E_X0C": 2.0}                   # applied before the probe
    assert s1.outcome.success and s1.outcome.measured == {"E_X0C": 4.0}   # 6 - 2
    assert model.learned == [(300.0, 4.0, 2.0)]          # residual + applied = total 6
    assert loop.step(600.0, {"a": 2.0}, {}).values == {"E_X0C": 6.0}
    assert loop.probe_times_s == [300.0] and sink.applied(600.0) == {"E_X0C": 6.0}


def test_apply_after_probe_probes_the_compensation_in_effect_and_applies_what_it_taught():
    model = LearnsTotalModel(probe_at={300.0})
    sink = HeldCompensation(model.component_names)
    loop = ClosedLoop(model, sink, probe=plant_probe, apply_after_probe=True)
    loop.step(0.0, {"a": 1.0}, {})
    s1 = loop.step(300.0, {"a": 2.0}, {})
    assert model.learned == [(300.0, 5.0, 1.0)]          # t=0's compensation still in effect
    assert s1.values == {"E_X0C": 6.0} and sink.applied(300.0) == {"E_X0C": 6.0}


def test_a_failed_probe_is_counted_and_never_learned_from():
    def broken(t, applied):
        raise ProbeFailed("probe signal lost")
    model = LearnsTotalModel(probe_at={0.0})
    loop = ClosedLoop(model, HeldCompensation(model.component_names), probe=broken)
    s = loop.step(0.0, {}, {})
    assert not s.outcome.success and s.outcome.reason == "probe signal lost"
    assert model.failed == [(0.0, "probe signal lost")] and model.learned == []
    assert loop.probing.state is ProbeState.IDLE and loop.probing.failed == 1


def test_an_asynchronous_probe_holds_one_cycle_and_ignores_a_second_due_while_running():
    model = LearnsTotalModel(probe_at={0.0, 300.0})
    sink = HeldCompensation(model.component_names)
    loop = ClosedLoop(model, sink, probing=ProbingStateMachine(result_wait_s=5.0), live=True)
    s0 = loop.step(0.0, {"a": 1.0}, {}, now_s=10.0)
    assert s0.action is Action.SEND_GOAL and loop.probing.busy
    assert loop.goal_sent() == {"E_X0C": 1.0}
    assert loop.accepted(0.0)
    s1 = loop.step(300.0, {"a": 1.0}, {}, now_s=11.0)    # due again, but one cycle at a time
    assert s1.action is Action.NONE and loop.probing.t_s == 0.0
    out = loop.probe_result(0.0, {"E_X0C": 4.0})
    assert out.success and model.learned == [(0.0, 4.0, 1.0)]
    assert loop.probe_result(0.0, {"E_X0C": 9.0}) is None   # a duplicate result: stale
    assert loop.probe_times_s == [0.0]


def test_an_asynchronous_probe_that_times_out_is_cancelled_and_counted():
    model = LearnsTotalModel(probe_at={0.0})
    loop = ClosedLoop(model, HeldCompensation(model.component_names),
                      probing=ProbingStateMachine(result_wait_s=5.0), live=True)
    loop.step(0.0, {}, {}, now_s=100.0)
    loop.goal_sent()
    assert loop.tick(104.0) == (Action.NONE, None)
    action, out = loop.tick(105.0)
    assert action is Action.CANCEL_GOAL and not out.success
    assert model.failed == [(0.0, out.reason)] and "within 5 s" in out.reason
    assert loop.probe_result(0.0, {"E_X0C": 1.0}) is None and model.learned == []


def test_live_a_result_the_model_refuses_becomes_a_failed_cycle():
    model = LearnsTotalModel(probe_at={0.0})
    loop = ClosedLoop(model, HeldCompensation(model.component_names), live=True)
    loop.step(0.0, {}, {})
    loop.goal_sent()
    out = loop.probe_result(0.0, {"E_X0C": math.nan})
    assert not out.success and out.reason == "result not usable: measured E_X0C is not finite"
    assert model.failed == [(0.0, out.reason)] and not loop.probing.busy


def test_live_late_repeated_and_rejected_instants():
    model = LearnsTotalModel()
    loop = ClosedLoop(model, HeldCompensation(model.component_names), live=True)
    first = loop.step(300.0, {"a": 1.0}, {})
    again = loop.step(300.0, {"a": 5.0}, {})
    assert again.kind is StepKind.REPEAT and again.values == first.values and model.updates == 1
    assert loop.step(0.0, {"a": 1.0}, {}).kind is StepKind.LATE and model.updates == 1
    model.t_last = 900.0                                 # the model refuses the next instant
    bad = loop.step(600.0, {}, {})
    assert bad.kind is StepKind.REJECTED and "goes back" in bad.error
    offline = ClosedLoop(LearnsTotalModel(), HeldCompensation(["E_X0C"]))
    offline.model.t_last = 900.0
    with pytest.raises(ValueError, match="goes back"):
        offline.step(600.0, {}, {})


def test_a_resumed_state_saved_after_the_graphs_first_instant_is_refused_once():
    model = LearnsTotalModel()
    resumed = ResumedState("/state/model.json", 37920.0)
    loop = ClosedLoop(model, HeldCompensation(model.component_names), resumed=resumed, live=True)
    with pytest.raises(ResumedStateMismatch) as err:
        loop.step(0.0, {}, {})
    msg = str(err.value)
    assert "/state/model.json" in msg and "37920.000 s" in msg and "first instant 0.000 s" in msg
    assert model.updates == 0                            # nothing learned from a refused state
    loop.replace_model(LearnsTotalModel())
    assert loop.step(0.0, {}, {}).kind is StepKind.NEW


def test_a_resumed_state_that_fits_the_graph_goes_on():
    model = LearnsTotalModel()
    loop = ClosedLoop(model, HeldCompensation(model.component_names),
                      resumed=ResumedState("m.json", 600.0), live=True)
    assert loop.step(600.0, {}, {}).kind is StepKind.NEW
    assert loop.step(900.0, {}, {}).kind is StepKind.NEW and loop.resumed is None
