"""TALC's switch-driven probing (TalcConfig.switch_probe_input): one extra probing a fixed delay
after a switch of a machine-state signal (the MWF flag), on top of the schedule."""
import math

import pytest

from talc_model.talc.model import TalcModel

H = 3600.0
CFG = {"component_names": ["E_X0C"], "input_names": ["ambient"], "post_cp_interval_h": 2.0,
       "cp_interval_s": 300.0, "switch_probe_input": "coolant_on", "switch_probe_delay_min": 30.0}


def _model(**over):
    m = TalcModel({**CFG, **over})
    m.update_inputs(0.0, {"ambient": 20.0}, {"coolant_on": 0.0})
    m.phase = "compensation"          # the schedule alone matters here
    m.last_probe_t = 0.0
    return m


def test_a_switch_makes_one_probe_due_after_the_delay_then_the_schedule_resumes():
    m = _model()
    regular = 2 * H + 95.0
    assert m.next_probe_due_s() == pytest.approx(regular)
    m.update_inputs(600.0, {"ambient": 20.0}, {"coolant_on": 1.0})          # M08 at 10 min
    assert m.next_probe_due_s() == pytest.approx(600.0 + 30 * 60.0)
    assert not m.probe_due(600.0 + 29 * 60.0) and m.probe_due(600.0 + 30 * 60.0)
    m.add_failed_measurement(600.0 + 30 * 60.0, "test")                     # the switch probing
    assert m.switch_probe_due_s is None
    assert m.next_probe_due_s() == pytest.approx(2400.0 + regular)


def test_no_switch_leaves_the_schedule_and_a_switch_while_pending_is_ignored():
    m = _model()
    for t in (300.0, 600.0, 900.0):
        m.update_inputs(t, {"ambient": 20.0}, {"coolant_on": 0.0})
    assert m.switch_probe_due_s is None and m.next_probe_due_s() == pytest.approx(2 * H + 95.0)
    m.update_inputs(1200.0, {"ambient": 20.0}, {"coolant_on": 1.0})
    m.update_inputs(1500.0, {"ambient": 20.0}, {"coolant_on": 0.0})        # switched back: still 1200 + 30 min
    assert m.switch_probe_due_s == pytest.approx(1200.0 + 1800.0)
    m.update_inputs(1800.0, {"ambient": 20.0}, {"coolant_on": math.nan})   # unknown: no decision
    assert m.switch_last == {"coolant_on": 0.0}


def test_off_by_default_and_state_round_trip():
    m = _model(switch_probe_input="")
    m.update_inputs(600.0, {"ambient": 20.0}, {"coolant_on": 1.0})
    assert m.switch_probe_due_s is None
    s = _model()
    s.update_inputs(600.0, {"ambient": 20.0}, {"coolant_on": 1.0})
    back = TalcModel.from_state(s.to_state())
    assert back.switch_probe_due_s == pytest.approx(2400.0) and back.switch_last == {"coolant_on": 1.0}
    old = s.to_state()
    del old["switch"]                                                     # a state saved before
    assert TalcModel.from_state(old).switch_probe_due_s is None
    old = s.to_state()
    old["switch"]["last"] = 1.0                                           # saved with one switch signal
    assert TalcModel.from_state(old).switch_last == {"coolant_on": 1.0}


def test_several_switch_signals_each_make_a_probing_due():
    m = _model(switch_probe_input="coolant_on, c_speed_rpm")
    m.update_inputs(300.0, {"ambient": 20.0}, {"coolant_on": 0.0, "c_speed_rpm": 300.0})
    m.update_inputs(600.0, {"ambient": 20.0}, {"coolant_on": 0.0, "c_speed_rpm": 900.0})   # a speed step
    assert m.switch_probe_due_s == pytest.approx(600.0 + 1800.0)
    m.add_failed_measurement(2400.0, "test")
    m.update_inputs(2700.0, {"ambient": 20.0}, {"coolant_on": 1.0, "c_speed_rpm": 900.0})  # M08
    assert m.switch_probe_due_s == pytest.approx(2700.0 + 1800.0)


@pytest.mark.parametrize("bad", [0.0, -5.0, math.inf])
def test_bad_delay_is_one_clear_error(bad):
    with pytest.raises(ValueError, match="switch_probe_delay_min"):
        TalcModel({**CFG, "switch_probe_delay_min": bad})


def test_a_non_numeric_switch_signal_names_the_input():
    m = _model()
    with pytest.raises(ValueError, match="coolant_on"):
        m.update_inputs(600.0, {"ambient": 20.0}, {"coolant_on": "on"})
