"""The adaptive mode's gain once the probes decide it: kept as far as the probes confirm it beyond
their noise, and then only the model's own band applies to its predicted change (a steady change
smaller than the readings' band per probing interval is followed once confirmed)."""
from __future__ import annotations

import numpy as np
import pytest

from talc_model.probing.uncertainty_weighted_hold import change_gain
from thermal_eval.evaluate.adaptive import (CONFIRM_SIGMAS, ProbingBudget, confirmed_gain, dead_band_um,
                                            model_band_um, online_gains, run_adaptive)
from thermal_eval.evaluate.spec import EvaluationData, Split


def test_a_gain_within_its_standard_errors_is_not_followed_and_a_clear_one_almost_whole():
    dp = np.array([1.0, 1.0])
    se = np.sqrt(2.0 * 0.2 ** 2 / 2.0)                    # two pairs of 0.2-um readings
    assert confirmed_gain([0.9 * CONFIRM_SIGMAS * se, 0.9 * CONFIRM_SIGMAS * se], dp, 0.2, 0.7) == 0.0
    assert confirmed_gain([-0.5, -0.5], dp, 0.2, 0.7) == 0.0
    big = confirmed_gain([3.0, 3.0], 3.0 * dp, 0.2, 0.7)
    assert 0.95 < big < 1.0
    assert confirmed_gain([0.1, -0.1], [0.0, 0.0], 0.2, 0.7) == 0.7        # no predicted change: the default
    rng = np.random.default_rng(0)
    dy, dq = rng.normal(0.5, 0.3, 4), rng.normal(0.5, 0.3, 4)
    assert confirmed_gain(dy, dq, 0.0, 0.3) == pytest.approx(change_gain(dy, dq, 0.3))   # no noise: least squares


def test_the_probes_decide_the_gain_after_two_pairs_with_a_predicted_change():
    y = np.array([0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 3.0])
    p = np.array([0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 3.0])
    gains, decided = online_gains(y, p, [0, 1, 2, 3, 4, 5, 6], 0.4, band=0.0, noise_um=0.01)
    assert decided.tolist() == [False, False, True, True, True, False, False]     # the model predicts nothing after 3
    assert gains[0] == gains[1] == 0.4 and gains[2] > 0.99 and gains[5] == gains[6] == 0.4


def test_the_model_band_leaves_out_the_readings_noise():
    rng = np.random.default_rng(3)
    n = 500
    y = rng.normal(0, 0.3, n)
    smooth = np.linspace(0.0, 3.0, n)
    assert model_band_um(y, n, 0.1, prediction=smooth) == 0.1
    assert dead_band_um(y, n, 0.1, prediction=smooth) > 0.7


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_steady_change_below_the_readings_band_is_followed_once_the_probes_confirm_it(seed):
    """A 0.8 um/h drift the model predicts exactly, read with 0.2-um noise and probed once an
    hour: each interval's change is within twice the readings' band, so the band alone follows
    about half of it (0.88 x holding); once two pairs of probes confirm the gain, the whole
    change beyond the model's own band is followed."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 30 * 3600.0, 60.0)
    n, n_train = t.size, int(18 * 3600 / 60)
    truth = 6.0 * (1 - np.exp(-np.minimum(t, 6 * 3600.0) / 7200.0)) + 0.8 * np.maximum(t - t[n_train - 1], 0.0) / 3600.0
    y = truth + rng.normal(0, 0.2, n)
    test = slice(n_train, n)
    d = EvaluationData(t, truth[:, None], ["m_c"], None, [], {"z_um": y}, Split(n_train, slice(n, n), test, n))
    res = run_adaptive(d, {"z_um": truth}, {"z_um": (truth.copy(), 600)}, ProbingBudget(probe_every_h=1.0))
    err = np.mean(np.abs(y[test] - res.compensation["z_um"][test]))
    hold = np.mean(np.abs(y[test] - res.hold["z_um"][test]))
    assert res.rates["z_um"]["dead_band_um"] > 0.5 and res.rates["z_um"]["model_band_um"] == 0.0
    assert err < 0.8 * hold
