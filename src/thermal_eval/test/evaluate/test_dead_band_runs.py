"""The adaptive mode's dead band and gain over runs laid end to end, and the characteristic
diagram's inputs per channel."""
from __future__ import annotations

import numpy as np

from talc_model.open_loop.sensor_selection import sensor_medoids
from thermal_eval.datasets.runs import Run, at_rest, fold_data
from thermal_comp_common.recording_sources import RunEntry
from thermal_eval.evaluate.adaptive import (ProbingBudget, dead_band_um, reading_noise_um, run_adaptive, shrink,
                                            training_gain, within_runs)
from thermal_eval.evaluate.open_loop_models import MODELS
from thermal_eval.evaluate.spec import EvaluationData, Split

CD = next(m for m in MODELS if m.name == "characteristic_diagram")


def _run(k: int, n: int = 200, noise: float = 0.2) -> Run:
    rng = np.random.default_rng(k)
    t = np.arange(n) * 60.0
    temp = 20.0 + 3.0 * k + 4.0 * (1.0 - np.exp(-t / 3600.0))
    y = 2.0 * (temp - temp[0]) + rng.normal(0.0, noise, n)
    y -= y[0]
    d = EvaluationData(t, temp[:, None], ["m_c"], None, [], {"z_um": y}, Split(n, slice(n, n), slice(n, n), n))
    return Run(RunEntry(f"r{k}.csv", f"r{k}"), d)


def test_rows_of_a_run_and_its_rest_are_marked_and_changes_stay_inside_one_run():
    runs = [_run(k) for k in range(4)]
    d = fold_data(runs, [0, 1, 2], 3, rest_h=1.0)
    ids = d.run_id
    assert ids is not None and ids.size == len(d) and set(np.unique(ids)) == {-1, 0, 1, 2, 3}
    assert np.sum(ids == -1) == 4 * 60 and np.all(ids[d.split.test] == 3)
    ok = within_runs(ids, len(d), 1)
    jumps = np.flatnonzero(np.diff(ids) != 0)
    assert not ok[jumps].any() and not ok[ids[:-1] == -1].any()
    # the rest rows' zero changes and the jumps back to 0 do not lower or raise the noise
    alone = reading_noise_um(np.concatenate([r.data.displacement_um["z_um"] for r in runs[:3]]), 600,
                             np.repeat([0, 1, 2], 200))
    marked = reading_noise_um(d.displacement_um["z_um"], d.split.n_train, ids)
    assert marked == alone
    assert reading_noise_um(d.displacement_um["z_um"], d.split.n_train) < 0.8 * marked
    assert within_runs(None, 10, 3).tolist() == [True] * 7


def test_the_training_gain_ignores_pairs_across_runs():
    """Runs whose displacement jumps back to 0 at each start while a model of absolute
    temperatures does not: across runs the pairs disagree; inside runs the model is right."""
    t = np.arange(600) * 60.0
    ids = np.repeat([0, 1, 2], 200)
    p = np.concatenate([np.linspace(0, 5, 200) + 10.0 * k for k in range(3)])
    y = p - 10.0 * ids
    assert training_gain(t, y, p, 0, 600, 1.0, 0.0, ids) == 1.0
    assert training_gain(t, y, p, 0, 600, 1.0, 0.0) < 0.9


def test_the_dead_band_zeroes_small_changes_and_keeps_large_ones_almost_whole():
    dp = np.array([0.0, 0.3, -0.5, 0.51, 2.0, -10.0, np.nan])
    s = shrink(dp, 0.5)
    assert s[:3].tolist() == [0.0, 0.0, 0.0] and abs(s[3]) < 0.03 and np.isnan(s[6])
    assert s[4] == 2.0 - 0.125 and abs(s[5] + 10.0) < 0.03          # a soft threshold would give 1.5, -9.5
    assert np.all(np.abs(s[:6]) <= np.abs(dp[:6]))
    assert shrink(np.array([0.2, -0.1]), 0.0).tolist() == [0.2, -0.1]


def test_the_dead_band_is_the_larger_of_the_readings_and_the_models_noise():
    """A predicted change the probes cannot tell from their noise is not acted on, nor one within
    the model's own noise; the probe's resolution bounds it from below."""
    rng = np.random.default_rng(3)
    n = 500
    y = np.cumsum(rng.normal(0, 0.01, n)) + rng.normal(0, 0.3, n)
    smooth = np.linspace(0.0, 3.0, n)
    noisier = smooth + rng.normal(0, 0.6, n)
    readings = dead_band_um(y, n, 0.1)
    assert 0.7 < readings < 1.0                                              # 2 sqrt(2) x 0.3
    assert dead_band_um(y, n, 0.1, prediction=smooth) == readings
    assert 1.4 < dead_band_um(y, n, 0.1, prediction=noisier) < 2.0          # 2 sqrt(2) x 0.6
    assert dead_band_um(np.zeros(n), n, 0.1, prediction=smooth) == 0.1


def test_the_diagram_finds_the_sensor_that_drives_a_channel():
    """Seven sensors, two slow fields of three and the one that drives the channel: the medoids
    of one or two groups are field sensors and miss it; the channel's most correlated sensor
    does not (seed 3: the fields' random walks group so that the medoids are field sensors)."""
    rng = np.random.default_rng(3)
    n = 600
    t = np.arange(n) * 120.0
    fields = [20.0 + np.cumsum(rng.normal(0, 0.05, n)) for _ in range(2)]
    temps = np.column_stack([f + rng.normal(0, 0.02, n) for f in fields for _ in range(3)]
                            + [22.0 + 3.0 * np.sin(t / 5000.0)])
    names = [f"f{i}_c" for i in range(6)] + ["drive_c"]
    assert all("drive_c" not in sensor_medoids(temps, k, names) for k in (1, 2))
    y = 4.0 * (temps[:, 6] - temps[0, 6]) + rng.normal(0, 0.05, n)
    d = EvaluationData(t, temps, names, None, [], {"z_um": y}, Split(n, slice(n, n), slice(n, n), n))
    params = CD.select(d, "z_um", n)
    assert "drive_c" in params["inputs"] and params["training_validation_rms_um"] < 0.5


def test_a_run_at_rest_marks_its_rest_rows():
    d = at_rest(_run(0).data, 0.5)
    assert d.run_id.tolist() == [-1] * 30 + [0] * 200
    assert at_rest(_run(0).data, 0.0).run_id is None


def test_on_a_noisy_plateau_small_predicted_drifts_are_not_followed():
    """Training rows where the model is right (a 6-um warm-up), then a 12-h plateau read with
    0.2-um probe noise on which the model predicts a slow drift of 0.4 um/h that does not
    happen: each hour's predicted change is below what two probe readings can tell apart, so the
    compensation holds (within 10 % of holding its probes), though the prediction itself is smooth."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 30 * 3600.0, 60.0)
    n, n_train = t.size, int(18 * 3600 / 60)
    truth = np.where(t < 6 * 3600, 6.0 * (1 - np.exp(-t / 7200.0)), 6.0 * (1 - np.exp(-6 * 3600 / 7200.0)))
    y = truth + rng.normal(0, 0.2, n)
    p = truth + np.where(t > t[n_train - 1], 0.4 * (t - t[n_train - 1]) / 3600.0, 0.0)
    test = slice(n_train, n)
    d = EvaluationData(t, truth[:, None], ["m_c"], None, [], {"z_um": y}, Split(n_train, slice(n, n), test, n))
    res = run_adaptive(d, {"z_um": p}, {"z_um": (p.copy(), 600)}, ProbingBudget(probe_every_h=1.0))
    err = np.mean(np.abs(y[test] - res.compensation["z_um"][test]))
    hold = np.mean(np.abs(y[test] - res.hold["z_um"][test]))
    assert err <= 1.10 * hold and res.rates["z_um"]["dead_band_um"] > 0.5
