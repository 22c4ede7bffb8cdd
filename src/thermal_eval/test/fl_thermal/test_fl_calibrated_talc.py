"""Calibrated TALC on FL_THERMAL: sub-grid evaluation of the ARX, no look at rows it must not see."""
import copy
import math

import numpy as np
import pytest

from talc_model.arx import ArxModel, ArxOrders
from thermal_eval.open_loop_models import subgrid_prediction
from thermal_eval.fl_thermal_calibrated_talc import (calibrated_talc_figures, run_calibrated_talc,
                                                   walk_forward_filter)
from thermal_eval.fl_thermal_data import CHANNELS, FlThermalError, Splits, load_fl_thermal
from talc_model.probe_update import ProbeSchedule

STEP = 20            # 5-min grid on 15-s rows


def _model():
    # y_k = 0.9 y_{k-1} + 0.5 u1_k + 0.2 u1_{k-1} - 0.3 u2_k
    return ArxModel(ArxOrders(na=1, nb=(2, 1)), np.array([-0.9, 0.5, 0.2, -0.3]))


def _simulate(model, u_grid, y0):
    y = np.empty(len(u_grid))
    y[0] = y0
    for k in range(1, len(u_grid)):
        y[k] = 0.9 * y[k - 1] + 0.5 * u_grid[k, 0] + 0.2 * u_grid[k - 1, 0] - 0.3 * u_grid[k, 1]
    return y


def test_subgrid_interpolates_exactly_when_the_inputs_already_hold_the_next_grid_value():
    rng = np.random.default_rng(3)
    n_grid = 30
    u_grid = np.cumsum(rng.normal(0, 1, (n_grid, 2)), axis=0)
    n = (n_grid - 1) * STEP + 1
    grid = np.arange(0, n, STEP)
    # rows after grid sample k already read the inputs of sample k + 1 (a step right after k)
    u_rows = u_grid[np.minimum((np.arange(n) + STEP - 1) // STEP, n_grid - 1)]
    model = _model()
    y = _simulate(model, u_grid, 1.0)
    out = subgrid_prediction(model, u_rows, grid, y, first=1)
    np.testing.assert_allclose(out[grid[1:]], y[1:])                        # grid rows: the simulation
    expected = np.interp(np.arange(grid[1], n), grid, y)                     # in between: linear
    np.testing.assert_allclose(out[grid[1]:], expected, atol=1e-12)
    assert np.all(np.isnan(out[:grid[1]]))


def test_subgrid_is_causal():
    rng = np.random.default_rng(4)
    n_grid = 12
    n = n_grid * STEP
    grid = np.arange(0, n, STEP)
    u_rows = np.cumsum(rng.normal(0, 0.2, (n, 2)), axis=0)
    model = _model()
    y = _simulate(model, u_rows[grid], 0.0)
    out = subgrid_prediction(model, u_rows, grid, y, first=1)
    cut = 5 * STEP + 7
    later = u_rows.copy()
    later[cut + 1:] += 50.0
    y_later = np.concatenate([y[:6], _simulate(model, later[grid], 0.0)[6:]])
    out_later = subgrid_prediction(model, later, grid, y_later, first=1)
    np.testing.assert_array_equal(out[:cut + 1], out_later[:cut + 1])
    assert not np.allclose(out[cut + 1:], out_later[cut + 1:])


@pytest.fixture(scope="module")
def slice_data(shared_dir):
    return load_fl_thermal(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv", rows=2400, every=4)


SMALL = dict(group_candidates=(2, 3), tau_grid=(3600.0, 14400.0), ratio_grid=(0.0, 1.0))


@pytest.mark.parametrize("load_probing", [False, True])
def test_calibrated_talc_sees_only_the_training_rows_and_its_own_probes(slice_data, load_probing):
    data = slice_data
    splits = Splits.authors(len(data))
    # no ACL phases with load probing, so that the spindle step at 8.1 h must start one itself
    schedule = ProbeSchedule(acl_um=math.inf if load_probing else 1.0)
    a = run_calibrated_talc(data, splits, schedule, load_probing=load_probing, **SMALL)
    poisoned = copy.deepcopy(data)
    seen = set(a.probe_rows)
    hidden = np.array([r for r in range(splits.n_train, splits.n) if r not in seen])
    for ch in CHANNELS:
        poisoned.displacement_um[ch][hidden] = 1e6
    b = run_calibrated_talc(poisoned, splits, schedule, load_probing=load_probing, **SMALL)
    assert a.probe_rows == b.probe_rows and a.filters == b.filters and a.evaluation == b.evaluation
    for ch in CHANNELS:
        np.testing.assert_array_equal(a.compensation[ch], b.compensation[ch])
        assert np.all(np.isfinite(a.compensation[ch][splits.n_train:]))
    assert (a.load_change_phases > 0) == load_probing
    figs = calibrated_talc_figures(data, splits, a)
    assert figs["calibration_probings"] == 72 and figs["probing_cycles_after_calibration"] == len(a.probe_rows) > 0
    assert figs["probing_cycles_test_rows"] + figs["probing_cycles_validation_rows"] == len(a.probe_rows)
    first = a.probe_rows[0]
    assert figs["first_probe_after_calibration_h"] == round(data.time_s[first] / 3600.0, 2)
    y, c = data.displacement_um["ch2"], a.compensation["ch2"]
    n_blind, n_seen = first - splits.n_train, splits.test_end - first
    whole = (figs["ch2"]["mae_before_first_probe_um"] * n_blind + figs["ch2"]["mae_from_first_probe_um"] * n_seen) \
        / (n_blind + n_seen)
    assert whole == pytest.approx(figs["ch2"]["mae_um"], abs=2e-3)         # the two parts make up the test MAE


def test_walk_forward_rejects_folds_without_room(slice_data):
    splits = Splits.authors(len(slice_data))
    with pytest.raises(FlThermalError, match="fold_starts"):
        walk_forward_filter(slice_data, splits, "ch1", ProbeSchedule(), fold_starts=(0.99,), **SMALL)
    with pytest.raises(FlThermalError, match="evaluations"):
        walk_forward_filter(slice_data, splits, "ch1", ProbeSchedule(), evaluations=("spline",), **SMALL)
