"""AGP fitted on the training rows (a closed-loop row of evaluate): sigma_max probes, rate limit, cap, no look ahead."""
import copy

import numpy as np
import pytest

from talc_model.open_loop.sensor_selection import SensorSelectionError, fast_sensor
from talc_model.loop.slow_error_filter import SlowErrorFilter, slow_error_compensation
from talc_model.probing.uncertainty_weighted_hold import HoldError, measured_hold_rate, uncertainty_weighted_hold
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.agp_rows import (AgpSchedule, agp_features, agp_input_sensors, fit_calibration_gps,
                                         replay_agp, run_training_fit_agp)
from thermal_eval.evaluate.training_fit import TrainingFitError
from thermal_eval.fl_thermal.data import SENSORS, as_evaluation_data, load_fl_thermal

DT = 15.0


@pytest.fixture(scope="module")
def slice_data(shared_dir):
    return as_evaluation_data(load_fl_thermal(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv", rows=2400, every=4))


def _synthetic(n=2400, jump_row=1200):
    """One input that sweeps 0..1 during calibration and jumps to 3 (never seen) at jump_row;
    two channels that are smooth functions of it."""
    rng = np.random.default_rng(5)
    t = np.arange(n) * DT
    x = np.where(np.arange(n) < jump_row, 0.5 + 0.5 * np.sin(t / 3000.0), 3.0)
    X = x[:, None]
    Y = np.column_stack([3.0 * x, -2.0 * x + 1.0]) + rng.normal(0, 0.05, (n, 2))
    return t, X, Y


def test_an_unseen_state_triggers_sigma_max_probes_no_closer_than_the_rate_limit():
    t, X, Y = _synthetic()
    start = 600
    cal = np.arange(0, start, 20)
    gps = fit_calibration_gps(X, Y, cal, max_err=10.0)
    schedule = AgpSchedule()
    tr = replay_agp(t, X, Y, start, len(t), gps, cal, 1.0, schedule)
    sigma = [r for r, why in zip(tr.probe_rows, tr.probe_reasons) if why == "sigma_max"]
    assert sigma and sigma[0] >= 1200                      # calm before the jump: no sigma_max probe
    assert t[sigma[0]] - t[1200] <= 15.0                   # ... and one right after it (rate limit long past)
    gaps = np.diff(t[tr.probe_rows])
    assert np.all(gaps >= schedule.min_sigma_probe_interval_s + schedule.probe_duration_s - 1e-9)
    # before the jump only control measurements, one per 2 h + cycle
    before = [r for r in tr.probe_rows if r < 1200]
    assert all(why == "control" for r, why in zip(tr.probe_rows, tr.probe_reasons) if r < 1200)
    assert np.allclose(np.diff(t[[int(cal[-1])] + before]), 7200.0 + 95.0, atol=DT)
    # the recalibration learnt the new state: the GP mean there is close to the truth afterwards
    k = sigma[-1] + 1
    assert abs(tr.mean[k, 0] - 9.0) < 1.0 and abs(tr.mean[k, 1] + 5.0) < 1.0
    assert tr.refits_optimised >= len(sigma)
    capped = replay_agp(t, X, Y, start, len(t), gps, cal, 1.0, AgpSchedule(max_probes_per_h=0.5))
    assert capped.refused_steps > 0 and len(capped.probe_rows) < len(tr.probe_rows)
    for i, r in enumerate(capped.probe_rows):          # never more than 0.5 per hour since calibration ended
        assert i + 1 <= 0.5 * (t[r] - t[start - 1]) / 3600.0


def test_the_gp_inputs_are_read_only_at_calibration_and_probe_rows():
    t, X, Y = _synthetic()
    start = 600
    cal = np.arange(0, start, 20)
    gps = fit_calibration_gps(X, Y, cal, max_err=10.0)
    tr = replay_agp(t, X, Y, start, len(t), gps, cal, 1.0, AgpSchedule())
    seen = set(cal.tolist()) | set(tr.probe_rows)
    poisoned = Y.copy()
    poisoned[[r for r in range(len(t)) if r not in seen]] = 1e6
    tr2 = replay_agp(t, X, poisoned, start, len(t), gps, cal, 1.0, AgpSchedule())
    assert tr2.probe_rows == tr.probe_rows and np.array_equal(tr2.mean, tr.mean, equal_nan=True)


def test_an_exact_probe_cancels_a_constant_error_from_the_next_row_and_decays_with_tau():
    n = 100
    t = np.arange(n) * 60.0
    y = np.full(n, 5.0)
    gp_mean = np.zeros(n)                  # the GP misses a constant 5 um
    probes = [40]
    post = np.array([0.0])
    held = slow_error_compensation(t, y, gp_mean, probes, post, 10, n, SlowErrorFilter(1e9, 0.0))
    assert np.all(np.isnan(held[:10])) and np.allclose(held[10:41], 0.0) and np.allclose(held[41:], 5.0, atol=1e-4)
    tau = 1800.0
    dec = slow_error_compensation(t, y, gp_mean, probes, post, 10, n, SlowErrorFilter(tau, 0.0))
    assert np.allclose(dec[41:], 5.0 * np.exp(-(t[41:] - t[40]) / tau))
    noisy = slow_error_compensation(t, y, gp_mean, probes, post, 10, n, SlowErrorFilter(1e9, 1.0))
    assert 0.0 < noisy[41] < 5.0                          # a noisy probe counts less than fully


def test_bad_settings_are_named(slice_data):
    with pytest.raises(TrainingFitError, match="min_sigma_probe_interval_s"):
        AgpSchedule(min_sigma_probe_interval_s=0.0)
    with pytest.raises(TrainingFitError, match="sensors"):
        agp_features(slice_data, ["t99"], ())
    with pytest.raises(TrainingFitError, match="sigma_max_ratios"):
        run_training_fit_agp(slice_data, ProbingBudget(), sigma_max_ratios=(1.5,))
    t, X, Y = _synthetic(200, 150)
    cal = np.arange(0, 100, 20)
    gps = fit_calibration_gps(X, Y, cal, max_err=10.0)
    with pytest.raises(TrainingFitError, match="sigma_max_um"):
        replay_agp(t, X, Y, 100, 200, gps, cal, float("nan"), AgpSchedule())


def test_training_fit_agp_on_a_real_slice_sees_only_the_training_rows_and_its_probes(slice_data):
    data = slice_data
    n = data.split.n_train
    budget = ProbingBudget(probe_every_h=2.0, max_probes_per_h=2.0)
    kw = dict(feature_tau_sets=((), (1800.0,)), sigma_max_ratios=(0.1,), fold_starts=(0.7,),
              tau_grid=(3600.0, 28800.0), ratio_grid=(0.0, 1.0))
    res = run_training_fit_agp(data, budget, **kw)
    rows = res.trajectory.probe_rows
    assert rows and all(r >= n for r in rows) and len(res.calibration_rows) == 72
    st = res.settings()
    assert st["sigma_max_probings"] + st["control_probings"] == len(rows)
    assert st["sigma_max_ratio"] == 0.1 and tuple(st["feature_taus_s"]) in {(), (1800.0,)}
    for ch in data.channels:
        assert np.all(np.isfinite(res.compensation[ch][n:]))
        f = st["filters"][ch]
        assert f["noise_ratio"] in (0.0, 1.0) and f["bias_time_constant_h"] in (1.0, 8.0)
    poisoned = copy.deepcopy(data)
    keep = np.zeros(len(data), bool)
    keep[:n] = True
    keep[rows] = True
    for ch in data.channels:
        poisoned.displacement_um[ch][~keep] = -1e6
    res2 = run_training_fit_agp(poisoned, budget, **kw)
    assert res2.trajectory.probe_rows == rows
    for ch in data.channels:
        assert np.array_equal(res2.compensation[ch], res.compensation[ch], equal_nan=True)


def test_the_fast_sensor_is_the_one_whose_fast_part_the_displacements_follow():
    rng = np.random.default_rng(11)
    n = 3000
    t = np.arange(n) * DT
    slow = np.linspace(0.0, 5.0, n)
    wiggle = np.sin(2 * np.pi * t / 1500.0)                 # a 25-min oscillation near the spindle
    T = slow[:, None] + rng.normal(0, 0.02, (n, len(SENSORS)))
    T[:, 6] += 3.0 * np.sin(2 * np.pi * t / 5000.0)          # large but slow swings on t7
    T[:, 3] += 0.5 * wiggle                                  # the wiggle on t4
    D = np.column_stack([2.0 * slow + 1.5 * np.roll(wiggle, 8), -slow - np.roll(wiggle, 8)])
    assert fast_sensor(t, T, D, SENSORS) == "t4"
    sensors = agp_input_sensors(T, SENSORS, time_s=t, displacements=D)
    assert sensors[-1] == "t4" and len(set(sensors)) == len(sensors)
    assert agp_input_sensors(T, SENSORS) == sensors[:-1]               # without displacements: the medoids only
    with pytest.raises(SensorSelectionError, match="temperatures"):
        fast_sensor(t, T[:, :5], D, SENSORS)


def test_the_uncertainty_weighted_hold_trusts_the_gp_where_it_is_sure_and_the_probe_where_not():
    n = 200
    t = np.arange(n) * 60.0
    y = np.zeros(n)
    y[[9, 100]] = [1.0, 4.0]                                 # the two measured values
    c = np.full(n, 10.0)                                      # the GP compensation
    std = np.where(np.arange(n) < 100, 0.01, 100.0)           # sure before row 100, lost after
    out = uncertainty_weighted_hold(t, y, c, std, [9, 100], 10, n, 1.0)
    assert np.all(np.isnan(out[:10]))
    assert np.allclose(out[20:100], 10.0, atol=0.01)          # small std: the GP
    assert out[100] == pytest.approx(1.0, abs=0.01)           # row 100 before its probe: lost, holds row 9
    assert np.all(np.abs(out[101:] - 4.0) < 0.01)             # huge std: the measurement of row 100
    assert np.array_equal(uncertainty_weighted_hold(t, y, c, std, [9, 100], 10, n, float("inf"))[10:], c[10:])
    held = uncertainty_weighted_hold(t, y, c, std, [9, 100], 10, n, 0.0)
    assert np.allclose(held[10:101], 1.0) and np.allclose(held[101:], 4.0)
    with pytest.raises(HoldError, match="hold_rate"):
        uncertainty_weighted_hold(t, y, c, std, [9, 100], 10, n, -1.0)
    with pytest.raises(HoldError, match="measured_rows"):
        uncertainty_weighted_hold(t, y, c, std, [10, 100], 10, n, 1.0)
    # a random walk with 4 um^2/h is measured as such
    rng = np.random.default_rng(3)
    tt = np.arange(20000) * DT
    walk = np.cumsum(rng.normal(0.0, np.sqrt(4.0 * DT / 3600.0), tt.size))
    assert measured_hold_rate(tt, walk, tt.size) == pytest.approx(4.0, rel=0.1)
    with pytest.raises(HoldError, match="lag_s"):
        measured_hold_rate(tt[:10], walk[:10], 10)
