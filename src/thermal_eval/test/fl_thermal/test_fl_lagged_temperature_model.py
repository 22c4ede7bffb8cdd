"""Lagged-temperature model: exponential filter, walk-forward folds, recovery of a known lagged system."""
import math

import numpy as np
import pytest

from talc_model.open_loop.lagged_temperature_model import (LaggedModelError, LaggedTemperatureModel, default_tau_grid,
                                                 exponential_filter, lagged_features, walk_forward_folds,
                                                 walk_forward_select)


@pytest.mark.parametrize("irregular", [False, True])
def test_exponential_filter_matches_the_analytic_step_response(irregular):
    rng = np.random.default_rng(1)
    dt = rng.uniform(5.0, 40.0, 400) if irregular else np.full(400, 15.0)
    t = 1000.0 + np.concatenate([[0.0], np.cumsum(dt)])
    x = np.ones((t.size, 2))
    x[0] = 0.0                                     # a unit step right after the first sample
    x[:, 1] *= 3.0                                 # second column: step of height 3
    tau = 600.0
    y = exponential_filter(t, x, tau)
    analytic = 1.0 - np.exp(-(t - t[0]) / tau)     # first-order lag, input held between samples
    np.testing.assert_allclose(y[:, 0], analytic, atol=1e-12)
    np.testing.assert_allclose(y[:, 1], 3.0 * analytic, atol=1e-12)
    assert y[-1, 0] > 0.99


def test_exponential_filter_holds_its_state_over_missing_readings():
    t = np.arange(0.0, 300.0, 15.0)
    x = np.ones(t.size)
    x[0] = 0.0
    x[5:9] = np.nan
    y = exponential_filter(t, x, 120.0)
    assert np.all(y[5:9] == y[4])
    assert np.all(np.isfinite(y)) and y[9] > y[4]


def test_exponential_filter_and_model_reject_bad_input_by_name():
    t = np.array([0.0, 15.0, 15.0, 30.0])
    with pytest.raises(LaggedModelError, match="time_s: sample 2"):
        exponential_filter(t, np.zeros(4), 60.0)
    with pytest.raises(LaggedModelError, match="tau_s"):
        exponential_filter(np.arange(4.0), np.zeros(4), -1.0)
    with pytest.raises(LaggedModelError, match="alpha"):
        LaggedTemperatureModel((600.0,), alpha=-1.0).fit(np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(LaggedModelError, match="taus_s"):
        LaggedTemperatureModel((math.inf,), alpha=1.0).fit_recording(np.arange(3.0), np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(LaggedModelError, match="not fitted"):
        LaggedTemperatureModel().predict(np.zeros((3, 3)))


@pytest.mark.parametrize("n_train,n_folds", [(6669, 4), (1000, 3), (240, 2), (101, 5)])
def test_walk_forward_folds_never_touch_rows_at_or_after_n_train(n_train, n_folds):
    folds = walk_forward_folds(n_train, n_folds)
    assert len(folds) == n_folds
    for fit_end, v0, v1 in folds:
        assert 0 < fit_end <= v0 < v1 <= n_train       # fit strictly before the scored block
    assert folds[-1][2] == n_train                        # the blocks tile the second half exactly
    assert all(folds[i][2] == folds[i + 1][1] for i in range(n_folds - 1))
    with pytest.raises(LaggedModelError, match="n_train"):
        walk_forward_folds(30, 4)


def _synthetic_plant(n=3000, seed=0):
    """Three temperatures driven by random heating steps; the displacement is a known lagged sum."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    heat = np.repeat(rng.uniform(0, 1, (n // 120 + 1, 3)), 120, axis=0)[:n]
    T = 20.0 + np.column_stack([exponential_filter(t, heat[:, i], tau) * gain
                                for i, (tau, gain) in enumerate([(900.0, 8.0), (2400.0, 5.0), (5000.0, 3.0)])])
    d = T - T[0]
    y = 2.0 * exponential_filter(t, d[:, 0], 1800.0) - 1.5 * d[:, 1] + 0.7 * exponential_filter(t, d[:, 2], 7200.0)
    return t, T, y


def test_lagged_model_recovers_a_known_lagged_system_out_of_sample():
    t, T, y = _synthetic_plant()
    n_train = 2000
    model = LaggedTemperatureModel((1800.0, 7200.0), alpha=1e-8).fit_recording(t[:n_train], T[:n_train], y[:n_train])
    pred = model.predict_recording(t, T)
    assert np.max(np.abs(pred[n_train:] - y[n_train:])) < 1e-4
    # in raw units: w = coef / scale; the generating weights come back
    w = model.coef_ / model.scale_
    m = T.shape[1]
    np.testing.assert_allclose([w[m + 0], w[1], w[2 * m + 2]], [2.0, -1.5, 0.7], atol=1e-4)


def test_walk_forward_selection_finds_the_true_lags_and_ignores_rows_after_n_train():
    t, T, y = _synthetic_plant(seed=3)
    rng = np.random.default_rng(5)
    y = y + rng.normal(0.0, 0.05, y.size)
    n_train = 2000
    grid = default_tau_grid((600.0, 1800.0, 7200.0, 28800.0))
    sel = walk_forward_select(t, T, y, n_train, grid, [1e-6, 1e-2, 10.0])
    assert sel.taus_s == (1800.0, 7200.0)
    assert sel.best_mae < 0.1
    # poison every row from n_train on: the selection must not change at all
    T_bad, y_bad = T.copy(), y.copy()
    T_bad[n_train:] = 1e6
    y_bad[n_train:] = np.nan
    sel_bad = walk_forward_select(t, T_bad, y_bad, n_train, grid, [1e-6, 1e-2, 10.0])
    assert sel_bad.mae_by_candidate == sel.mae_by_candidate
    assert all(v1 <= n_train for _, _, v1 in sel.folds)


def test_features_are_causal():
    t, T, _ = _synthetic_plant(n=600)
    full = lagged_features(t, T, (600.0, 3600.0), exogenous=T[:, 0] * 0.1, exogenous_taus_s=(900.0,))
    cut = lagged_features(t[:400], T[:400], (600.0, 3600.0), exogenous=T[:400, 0] * 0.1, exogenous_taus_s=(900.0,))
    np.testing.assert_allclose(full[:400], cut, atol=1e-12)
    assert full.shape[1] == 3 * 3 + 2
