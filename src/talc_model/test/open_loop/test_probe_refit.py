"""Re-fitting the ridge at each probing (talc_model.open_loop.probe_refit)."""
from __future__ import annotations

import numpy as np
import pytest

from talc_model.open_loop.lagged_temperature_model import LaggedTemperatureModel
from talc_model.open_loop.probe_gain_update import regular_probes
from talc_model.open_loop.probe_refit import RefitError, choose_refit, ridge_refit

TAUS = (1800.0,)
ALPHA = 1.0


def _gain_change(n=3000, n_train=1500, seed=0):
    """Two temperatures with different slow courses; from ``n_train`` on the machine's gain on the
    first doubles (1.0 -> 2.0 um/K; the displacement stays continuous), the second's stays."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    temps = np.column_stack([3 * np.sin(t / 9000.0) + 0.5 * np.sin(t / 2100.0),
                             2 * (1 - np.exp(-t / 40000.0)) + 0.4 * np.cos(t / 5000.0)])
    after = np.arange(n) >= n_train
    y = temps[:, 0] + after * (temps[:, 0] - temps[n_train, 0]) - 0.7 * temps[:, 1] + rng.normal(0, 0.01, n)
    return t, temps, y, n_train


def _mae(a, b):
    return float(np.mean(np.abs(a - b)))


def test_the_refit_follows_a_gain_that_changes_after_training():
    t, temps, y, n_train = _gain_change()
    measured = [n_train - 1] + regular_probes(t, n_train, len(t), 3600.0)
    base = ridge_refit(t, temps, y, n_train, TAUS, ALPHA)
    held = base.compensation(y, measured, n_train, len(t))
    refit = base.with_update(0.3, True).compensation(y, measured, n_train, len(t))
    late = n_train + (len(t) - n_train) // 2            # once a dozen probes have been made
    assert _mae(y[late:], refit[late:]) < 0.3 * _mae(y[late:], held[late:])
    assert _mae(y[n_train:], refit[n_train:]) < 0.6 * _mae(y[n_train:], held[n_train:])
    coef_late = base.with_update(0.3, True).coefficients(y, measured[1:])
    coef_train = base.coefficients(y, [])
    assert coef_late[0] > 1.5 * coef_train[0]          # the first temperature's coefficient grew
    # it reads the displacement at measured rows only
    poisoned = np.full_like(y, 1e6)
    poisoned[measured] = y[measured]
    again = base.with_update(0.3, True).compensation(poisoned, measured, n_train, len(t))
    assert np.array_equal(refit[n_train:], again[n_train:]) and np.isnan(again[:n_train]).all()


def test_weight_zero_is_the_training_model_plus_its_residual_at_the_last_probe():
    t, temps, y, n_train = _gain_change()
    measured = [n_train - 1] + regular_probes(t, n_train, len(t), 3600.0)
    model = LaggedTemperatureModel(TAUS, ALPHA).fit_recording(t[:n_train], temps[:n_train], y[:n_train])
    p = model.predict_recording(t, temps)
    rows = np.arange(n_train, len(t))
    last = np.asarray(measured)[np.searchsorted(measured, rows, side="left") - 1]
    offset = p[rows] + y[last] - p[last]
    for own in (False, True):
        c = ridge_refit(t, temps, y, n_train, TAUS, ALPHA, 0.0, own).compensation(y, measured, n_train, len(t))
        assert np.allclose(c[rows], offset, rtol=0, atol=1e-9)


def test_the_choice_of_weight_reads_no_row_after_the_walk_forward():
    t, temps, y, n_train = _gain_change(n=3000, n_train=2400)
    # inside the training rows: fitted on rows < 1200, the gain changes at 2400, so the walk-forward
    # [1200, 2400) sees an unchanged machine; put the change inside it instead
    y = np.where(np.arange(len(t)) < 1800, y, y + temps[:, 0])
    half = ridge_refit(t, temps, y, 1200, TAUS, ALPHA)
    (w, own), scores = choose_refit(t, y, half, 1200, 2400, 3600.0, phases=3)
    assert scores[f"{w:g}/{'own' if own else 'shared'}"] == min(scores.values())
    assert w > 0 and scores["0/shared"] > min(scores.values())     # the change rewards a re-fit
    poisoned = y.copy()
    poisoned[2400:] = 1e6
    half2 = ridge_refit(t, temps, poisoned, 1200, TAUS, ALPHA)
    assert choose_refit(t, poisoned, half2, 1200, 2400, 3600.0, phases=3) == ((w, own), scores)


def test_bad_input_names_the_argument():
    t, temps, y, n_train = _gain_change(n=400, n_train=200)
    base = ridge_refit(t, temps, y, n_train, TAUS, ALPHA)
    with pytest.raises(RefitError, match="weight"):
        base.with_update(-1.0, False)
    with pytest.raises(RefitError, match="measured"):
        base.compensation(y, [250], n_train, len(t))
    with pytest.raises(RefitError, match="walk-forward rows"):
        choose_refit(t, y, base, 300, 200, 3600.0)
    with pytest.raises(RefitError, match="phases"):
        choose_refit(t, y, base, 100, 200, 3600.0, phases=0)
