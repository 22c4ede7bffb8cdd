"""The probes' re-estimation of each input's gain (talc_model.open_loop.probe_gain_update) and the
lagged ridge's contributions it works on."""
from __future__ import annotations

import numpy as np
import pytest

from talc_model.open_loop.lagged_temperature_model import LaggedTemperatureModel
from talc_model.open_loop.probe_gain_update import (GainUpdateError, choose_penalty, gain_errors, lagged_contributions,
                                                    regained_compensation, regular_probes)


def _drifting_gain(n=2000, err=(0.3, 0.0), seed=0):
    """Two smooth contributions; the machine's gain of the first is 30 % above the model's."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    x = np.column_stack([5 * np.sin(t / 20000.0), 3 * (1 - np.exp(-t / 30000.0))])
    p = x.sum(axis=1)
    y = p + x @ np.asarray(err) + rng.normal(0, 0.01, n)
    return t, x, p, y


def test_the_probes_recover_a_wrong_input_gain():
    t, x, p, y = _drifting_gain()
    measured = [99] + regular_probes(t, 100, len(t), 3600.0)
    d = gain_errors(y, p, x, measured, penalty=0.1)
    assert np.allclose(d[-1], [0.3, 0.0], atol=0.02)
    assert np.allclose(d[0], 0.0)     # before any pair: the calibrated gains


def test_the_regained_model_beats_the_plain_offset_and_sees_only_its_probes():
    t, x, p, y = _drifting_gain()
    start = 100
    measured = [start - 1] + regular_probes(t, start, len(t), 3600.0)
    c = regained_compensation(y, p, x, measured, start, len(t), penalty=1.0)
    seg = np.searchsorted(measured, np.arange(start, len(t)), side="left") - 1
    m = np.asarray(measured)[seg]
    offset = p[start:] + y[m] - p[m]
    assert np.mean(np.abs(y[start:] - c[start:])) < 0.5 * np.mean(np.abs(y[start:] - offset))
    poisoned = np.full_like(y, 1e6)
    poisoned[measured] = y[measured]
    c2 = regained_compensation(poisoned, p, x, measured, start, len(t), penalty=1.0)
    assert np.array_equal(c[start:], c2[start:]) and np.isnan(c2[:start]).all()


def test_the_walk_forward_penalty_uses_only_rows_before_its_stop():
    t, x, p, y = _drifting_gain()
    best, scores = choose_penalty(t, y, p, x, 500, 1500, 3600.0)
    assert scores[f"{best:g}"] == min(scores.values())
    y2 = y.copy()
    y2[1500:] = 1e6
    assert choose_penalty(t, y2, p, x, 500, 1500, 3600.0) == (best, scores)
    # the true gain error is large: the loosest prior wins over the tightest
    assert scores["1"] < scores["1000"]


def test_bad_input_names_the_argument():
    t, x, p, y = _drifting_gain(n=50)
    with pytest.raises(GainUpdateError, match="penalty"):
        gain_errors(y, p, x, [0, 10], penalty=0.0)
    with pytest.raises(GainUpdateError, match="measured"):
        regained_compensation(y, p, x, [20, 30], 10, 50, 1.0)
    with pytest.raises(GainUpdateError, match="contributions"):
        gain_errors(y, p, x[:10], [0, 10], penalty=1.0)


def _lagged_fit(seed=4, n=1500, gain=1.0):
    """A lagged ridge fitted on the first 900 rows of two temperatures; later rows' machine has
    ``gain`` x the sensitivity to the first sensor's 1-h low-pass (a drifted gain)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    temps = np.column_stack([20 + 3 * np.sin(t / 9000.0) + 0.02 * rng.normal(size=n),
                             22 + 2 * (1 - np.exp(-t / 20000.0))])
    m = LaggedTemperatureModel((3600.0,), 0.1).fit_recording(t[:900], temps[:900], np.zeros(900))
    feats = m.features(t, temps)
    y = 4.0 * feats[:, 2] - 2.0 * feats[:, 1]
    y[900:] += (gain - 1.0) * 4.0 * feats[900:, 2]
    m.fit_recording(t[:900], temps[:900], y[:900])
    return t, feats, y, m


def test_lagged_contributions_add_up_to_the_prediction():
    t, feats, y, m = _lagged_fit()
    x = lagged_contributions(m, feats)
    assert x.shape == (len(t), 4)
    assert np.allclose(m.intercept_ + x.sum(axis=1), m.predict(feats), atol=1e-9)


def test_the_probes_recover_a_drifted_lagged_gain():
    t, feats, y, m = _lagged_fit(gain=1.3)
    p, x = m.predict(feats), lagged_contributions(m, feats)
    measured = [899] + regular_probes(t, 900, len(t), 3600.0)
    fixed = regained_compensation(y, p, x, measured, 900, len(t), penalty=1e9)     # gains held at calibration
    free = regained_compensation(y, p, x, measured, 900, len(t), penalty=0.1)
    late = slice(1200, len(t))
    assert np.mean(np.abs(y[late] - free[late])) < 0.5 * np.mean(np.abs(y[late] - fixed[late]))   # 0.13 against 0.40 um


def _jumping_gain(n=6000, seed=0):
    """The first contribution's gain error jumps from 0 to +0.5 halfway (a changed machine)."""
    t, x, p, _ = _drifting_gain(n=n, seed=seed)
    x = np.column_stack([5 * np.sin(t / 5000.0), 3 * (1 - np.exp(-t / 30000.0))])
    p = x.sum(axis=1)
    err = np.where(t < t[n // 2], 0.0, 0.5)
    y = p + err * x[:, 0] + np.random.default_rng(seed).normal(0, 0.01, n)
    return t, x, p, y


def test_forgetting_follows_a_gain_that_changes_and_one_is_the_plain_update():
    t, x, p, y = _jumping_gain()
    measured = [99] + regular_probes(t, 100, len(t), 3600.0)
    plain = gain_errors(y, p, x, measured, penalty=1.0)
    assert np.array_equal(gain_errors(y, p, x, measured, penalty=1.0, forgetting=1.0), plain)
    fading = gain_errors(y, p, x, measured, penalty=1.0, forgetting=0.7)
    assert abs(fading[-1][0] - 0.5) < 0.05 < abs(plain[-1][0] - 0.5)
    with pytest.raises(GainUpdateError, match="forgetting: 1.5"):
        gain_errors(y, p, x, measured, penalty=1.0, forgetting=1.5)


def test_the_walk_forward_chooses_forgetting_over_phases_and_one_phase_is_choose_penalty():
    from talc_model.open_loop.probe_gain_update import choose_update, regular_probes as probes
    t, x, p, y = _jumping_gain()
    (pen, f), scores = choose_update(t, y, p, x, 1000, len(t), 3600.0, forgettings=(1.0, 0.7), phases=3)
    assert f == 0.7 and set(scores) == {f"{a:g}/{b:g}" for a in (1, 10, 100, 1000) for b in (1, 0.7)}
    assert probes(t, 1000, len(t), 3600.0, 1200.0)[0] == probes(t, 1000, len(t), 3600.0)[0] + 20   # 60-s rows
    assert choose_update(t, y, p, x, 1000, len(t), 3600.0)[0][0] == choose_penalty(t, y, p, x, 1000, len(t), 3600.0)[0]
