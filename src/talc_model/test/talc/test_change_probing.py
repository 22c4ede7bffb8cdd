"""TALC's own probing rule (TalcConfig.change_probe_threshold): a probing is due once the model's
predicted change since the last probing exceeds the threshold times the probe noise."""
import math

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders
from talc_model.talc.model import TalcModel

H = 3600.0
CFG = {"component_names": ["E_X0C", "E_A0C"], "angular_components": ["E_A0C"], "input_names": ["ambient"],
       "post_cp_interval_h": 2.0, "probe_noise_linear_um": 0.25, "probe_noise_angular_um_per_m": 1.2,
       "change_probe_threshold": 4.0, "change_probe_min_interval_min": 20.0,
       "change_probe_min_q_prod_pct": 90.0}


def _model(gain_lin=1.0, gain_ang=0.0, **over):
    """A static model E = gain * delta ambient, compensating, last probed at 0 s."""
    m = TalcModel({**CFG, **over})
    m.models = {"E_X0C": ArxModel(ArxOrders(0, (1,)), np.array([gain_lin])),
                "E_A0C": ArxModel(ArxOrders(0, (1,)), np.array([gain_ang]))}
    m.phase = "compensation"
    m.update_inputs(0.0, {"ambient": 20.0}, {})
    m.last_probe_t = 0.0
    m.probe_due(0.0)                      # creates the grid sample at 0 s
    return m


def _ramp_until(m, t_end, rate_k_per_h=0.7):
    """Ambient rising at ``rate_k_per_h``; the first instant (5-min grid) a probing is due."""
    for t in np.arange(300.0, t_end + 1.0, 300.0):
        m.update_inputs(float(t), {"ambient": 20.0 + rate_k_per_h * t / H}, {})
        if m.probe_due(float(t)):
            return float(t)
    return None


def test_a_predicted_change_beyond_threshold_times_noise_makes_a_probing_due():
    # 0.7 K/h x 1 um/K: 1 um (= 4 x 0.25 um) is passed after 86 min, before the 2 h schedule
    due = _ramp_until(_model(), 2 * H)
    assert due == pytest.approx(90 * 60.0)


def test_no_predicted_change_keeps_the_regular_schedule():
    m = _model(gain_lin=0.0)
    assert _ramp_until(m, 3 * H) == pytest.approx(2 * H + 300.0)   # the first grid instant past 2 h + 95 s


def test_angular_components_are_weighed_by_their_own_noise():
    # 1 um/m per K on E_A0C: 4 x 1.2 um/m is passed after 6.86 h of 0.7 K/h (a linear component: 1.4 h)
    m = _model(gain_lin=0.0, gain_ang=1.0, post_cp_interval_h=12.0)
    assert _ramp_until(m, 12 * H) == pytest.approx(415 * 60.0)


def test_not_earlier_than_the_minimum_interval():
    m = _model(gain_lin=100.0)            # the threshold is passed at the first grid sample
    assert _ramp_until(m, 2 * H) == pytest.approx(20 * 60.0)


def test_off_by_default_and_not_in_other_phases():
    assert _ramp_until(_model(change_probe_threshold=math.inf), 2 * H) is None
    m = _model()
    m.phase = "no_good"
    m.config.ng_interval_min = 600.0
    assert _ramp_until(m, 2 * H) is None


def test_the_rule_keeps_the_probing_budget():
    # one probing (at 0 s) so far; one more at 90 min: Q_prod 100 (1 - 2 x 95 s / 5400 s) = 96.5 %
    for floor, due in ((97.5, None), (96.0, 90 * 60.0)):
        m = _model(change_probe_min_q_prod_pct=floor)
        m.grid.measured[0, :] = True
        assert _ramp_until(m, 2 * H) == (None if due is None else pytest.approx(due))


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan])
def test_bad_threshold_is_one_clear_error(bad):
    with pytest.raises(ValueError, match="change_probe_threshold"):
        TalcModel({**CFG, "change_probe_threshold": bad})


def test_zero_probe_noise_with_the_rule_on_is_refused():
    with pytest.raises(ValueError, match="probe_noise_linear_um"):
        TalcModel({**CFG, "probe_noise_linear_um": 0.0})


@pytest.mark.parametrize("bad", [100.0, -1.0, math.nan])
def test_bad_q_prod_floor_is_one_clear_error(bad):
    with pytest.raises(ValueError, match="change_probe_min_q_prod_pct"):
        TalcModel({**CFG, "change_probe_min_q_prod_pct": bad})
