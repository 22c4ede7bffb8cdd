"""The change-probing threshold derived from a prior's training programme (talc_model.probing.change_threshold)
and the budget that does not charge a prior's check phase (change_probing.change_probe_due)."""
import math

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders
from talc_model.probing.change_probing import change_probe_due
from talc_model.probing.change_threshold import (ChangeThresholdError, between_probe_changes, change_figures,
                                         prior_change_thresholds)


def _static(gain):
    """y[k] = y[k-1] + gain * u (one pole at 1, u = 1): from a probing on, the model predicts a
    change of ``gain`` per grid sample."""
    return ArxModel(ArxOrders(1, (1,)), np.array([-1.0, float(gain)]))


def _ramp(n=240):
    """The input (a constant 1) and a true error rising by 1 per grid sample."""
    return np.ones((n, 1)), np.arange(n, dtype=float)


def test_a_perfect_model_has_no_error_share_and_holding_loses_the_change():
    u, y = _ramp()
    dp, dy = between_probe_changes(_static(2.0), u, 2.0 * y, 24)
    f = change_figures(dp, dy)
    assert f["share"] == pytest.approx(0.0, abs=1e-12)
    assert np.max(np.abs(dy)) == pytest.approx(2.0 * 23)         # the change over one interval
    assert f["hold_p99"] == pytest.approx(np.percentile(np.abs(dy), 99))


def test_a_model_predicting_double_the_change_has_share_one():
    u, y = _ramp()
    f = change_figures(*between_probe_changes(_static(2.0), u, y, 24))
    assert f["share"] == pytest.approx(0.5)        # error = dp / 2 at every sample
    f = change_figures(*between_probe_changes(_static(0.5), u, y, 24))
    assert f["share"] == pytest.approx(1.0)        # error = dp


def test_threshold_is_goal_times_group_hold_over_share_and_noise():
    u, y = _ramp()
    models = {"a": _static(2.0), "b": _static(6.0), "ang": _static(0.05)}
    errors = {"a": 1.0 * y, "b": 3.0 * y, "ang": 0.1 * y}
    noise = {"a": 0.25, "b": 0.25, "ang": 1.2}
    out = prior_change_thresholds(models, u, errors, 24, noise, {"a": "lin", "b": "lin", "ang": "ang"}, 0.5)
    level = 0.5 * (out["a"]["hold_p99"] + out["b"]["hold_p99"]) / 2
    assert out["a"]["level"] == out["b"]["level"] == pytest.approx(level)
    assert out["a"]["share"] == pytest.approx(0.5) and out["b"]["share"] == pytest.approx(0.5)
    assert out["a"]["threshold"] == pytest.approx(level / 0.5 / 0.25)
    # the angular group's level (0.5 x 2.3 um/m) is below one probe's own P99 noise (2.576 x 1.2): no threshold
    assert out["ang"]["level"] < 2.576 * 1.2 and math.isinf(out["ang"]["threshold"])


def test_no_predicted_change_gives_no_threshold():
    u, y = _ramp()
    out = prior_change_thresholds({"a": _static(0.0)}, u, {"a": 5.0 * y}, 24, {"a": 0.25}, {"a": "lin"})
    assert math.isinf(out["a"]["share"]) and math.isinf(out["a"]["threshold"])


@pytest.mark.parametrize("kwargs, field", [({"interval": 0}, "interval"), ({"goal": 0.0}, "goal"),
                                           ({"noise": {"a": 0.0}}, "noise"), ({"groups": {"x": "lin"}}, "groups")])
def test_bad_input_is_one_clear_error(kwargs, field):
    u, y = _ramp()
    args = {"models": {"a": _static(1.0)}, "u": u, "errors": {"a": y}, "interval": 24,
            "noise": {"a": 0.25}, "groups": {"a": "lin"}, "goal": 0.5}
    args.update(kwargs)
    with pytest.raises(ChangeThresholdError, match=field):
        prior_change_thresholds(**args)


def _due(budget_start_s, n=25, probed=range(0, 13)):
    """Grid of 5-min samples; probings at ``probed`` (a check phase: the first hour every 5 min);
    a predicted change far beyond the threshold at the newest sample."""
    x = np.zeros((n, 1))
    x[-1, 0] = 100.0
    measured = np.zeros((n, 1), bool)
    measured[list(probed), 0] = True
    return change_probe_due(x, measured, 12, (n - 1) * 300.0, 0.0, 300.0, np.array([0.25]), np.array([4.0]),
                            95.0, 97.5, budget_start_s)


def test_the_check_phase_is_not_charged_to_the_budget():
    # 13 probings in the first hour: Q_prod over the 2 h since the start is 82 %, over the budget
    assert _due(None) is False
    # counted from the check phase's end (1 h): the probing at 1 h and this one, 2 x 95 s in 1 h: 94.7 %
    assert _due(3600.0) is False
    # from 1 h 5 min: this one alone in 55 min, 97.1 % -- still below 97.5 %; with a longer quiet time it is due
    assert _due(3600.0, n=49) is True                     # 2 probings in 3 h since 1 h: 98.2 %


def test_per_component_thresholds_and_inf_never_fire():
    x = np.zeros((5, 2))
    x[-1] = [1.0, 100.0]
    measured = np.zeros((5, 2), bool)
    args = (x, measured, 0, 1200.0, 0.0, 300.0, np.array([0.25, 1.2]))
    assert change_probe_due(*args, np.array([8.0, math.inf]), 95.0, 0.0) is False     # 4 sigma < 8; inf never
    assert change_probe_due(*args, np.array([3.0, math.inf]), 95.0, 0.0) is True


def test_talc_uses_per_component_thresholds_set_on_the_model():
    from talc_model.talc.model import TalcModel
    cfg = {"component_names": ["E_X0C", "E_A0C"], "angular_components": ["E_A0C"], "input_names": ["ambient"],
           "post_cp_interval_h": 2.0, "change_probe_min_q_prod_pct": 90.0}

    def first_due(thresholds):
        m = TalcModel(cfg)                # the config's threshold is off (inf)
        m.models = {"E_X0C": ArxModel(ArxOrders(0, (1,)), np.array([1.0])),
                    "E_A0C": ArxModel(ArxOrders(0, (1,)), np.array([0.0]))}
        m.phase = "compensation"
        m.update_inputs(0.0, {"ambient": 20.0}, {})
        m.last_probe_t = 0.0
        m.probe_due(0.0)
        m.change_thresholds = None if thresholds is None else np.array(thresholds)
        for t in np.arange(300.0, 3 * 3600.0, 300.0):
            m.update_inputs(float(t), {"ambient": 20.0 + 0.7 * t / 3600.0}, {})   # 1 um/K on E_X0C
            if m.probe_due(float(t)):
                return float(t)
        return None

    assert first_due([4.0, math.inf]) == pytest.approx(90 * 60.0)     # 4 x 0.25 um after 86 min
    assert first_due([8.0, math.inf]) == pytest.approx(2 * 3600.0 + 300.0)   # 2 um only after 171 min: schedule
    assert first_due(None) == first_due([math.inf, math.inf]) == pytest.approx(2 * 3600.0 + 300.0)


def test_several_training_grids_are_pooled():
    u, y = _ramp()
    one = prior_change_thresholds({"a": _static(2.0)}, u, {"a": y}, 24, {"a": 0.25}, {"a": "lin"})
    steep = prior_change_thresholds({"a": _static(2.0)}, u, {"a": 3.0 * y}, 24, {"a": 0.25}, {"a": "lin"})
    both = prior_change_thresholds({"a": _static(2.0)}, [u, u], [{"a": y}, {"a": 3.0 * y}], 24, {"a": 0.25},
                                   {"a": "lin"})
    assert one["a"]["share"] == pytest.approx(0.5) and steep["a"]["share"] == pytest.approx(0.5)
    assert both["a"]["share"] == pytest.approx(0.5)       # error 1 of every predicted 2 in both
    assert one["a"]["hold_p99"] < both["a"]["hold_p99"] <= steep["a"]["hold_p99"]   # P99 of the pooled changes
