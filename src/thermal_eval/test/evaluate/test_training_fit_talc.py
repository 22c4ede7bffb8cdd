"""TALC fitted on the training rows (a closed-loop row of evaluate): sub-grid ARX, budget, no look ahead."""
import copy
import math

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders
from thermal_eval.evaluate.open_loop_models import subgrid_prediction
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.talc_rows import run_training_fit_talc, walk_forward_filter
from thermal_eval.evaluate.training_fit import TrainingFitError
from thermal_eval.evaluate.model_rows import run_closed_loop
from thermal_eval.fl_thermal.data import as_evaluation_data, load_fl_thermal

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
    return as_evaluation_data(load_fl_thermal(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv", rows=2400, every=4))


SMALL = dict(group_candidates=(2, 3), tau_grid=(3600.0, 14400.0), ratio_grid=(0.0, 1.0))


@pytest.mark.parametrize("load_probing", [False, True])
def test_training_fit_talc_sees_only_the_training_rows_and_its_own_probes(slice_data, load_probing):
    data = slice_data
    n = data.split.n_train
    # a huge tolerance with load probing: no ACL phases, so the spindle step at 8.1 h must start one itself
    budget = ProbingBudget(probe_every_h=1.0, max_probes_per_h=2.0, tolerance_um=1e6 if load_probing else 1.0)
    a = run_training_fit_talc(data, budget, load_probing=load_probing, **SMALL)
    poisoned = copy.deepcopy(data)
    seen = set(a.probe_rows)
    hidden = np.array([r for r in range(n, len(data)) if r not in seen])
    for ch in data.channels:
        poisoned.displacement_um[ch][hidden] = 1e6
    b = run_training_fit_talc(poisoned, budget, load_probing=load_probing, **SMALL)
    assert a.probe_rows == b.probe_rows and a.settings == b.settings and a.probe_rows
    for ch in data.channels:
        np.testing.assert_array_equal(a.compensation[ch], b.compensation[ch])
        assert np.all(np.isfinite(a.compensation[ch][n:]))
    assert (a.load_change_phases > 0) == load_probing
    assert len(a.calibration_rows) == 72 and a.calibration_rows[-1] < n     # 360 rows of 60 s, 5-min grid


def test_the_budget_caps_its_probings_and_the_row_counts_them(slice_data):
    data = slice_data
    t, n = data.time_s, data.split.n_train
    loose = run_training_fit_talc(data, ProbingBudget(probe_every_h=0.5, max_probes_per_h=100.0), **SMALL)
    capped = run_training_fit_talc(data, ProbingBudget(probe_every_h=0.5, max_probes_per_h=1.0), **SMALL)
    assert len(capped.probe_rows) < len(loose.probe_rows) and capped.refused_steps > 0
    for i, r in enumerate(capped.probe_rows):       # never more than one per hour since calibration ended
        assert i + 1 <= (t[r] - t[n - 1]) / 3600.0
    row = run_closed_loop(data, "talc_calibrated", ProbingBudget(probe_every_h=2.0, max_probes_per_h=1.0))
    assert row["probe_rows"][:72] == list(range(0, n, 5)) and row["calibration_probings"] == 72
    after = row["probe_rows_after_calibration"]
    assert after == row["probe_rows"][72:] and row["probings_after_calibration"] == len(after) > 0
    assert row["calibration_end_h"] == round((t[n - 1] - t[0]) / 3600.0, 2)
    assert row["q_prod_pct"] < row["q_prod_after_calibration_pct"] < 100.0


def test_bad_settings_are_named(slice_data):
    budget = ProbingBudget()
    with pytest.raises(TrainingFitError, match="fold_starts"):
        walk_forward_filter(slice_data, "ch1", budget, fold_starts=(0.99,), **SMALL)
    with pytest.raises(TrainingFitError, match="evaluations"):
        walk_forward_filter(slice_data, "ch1", budget, evaluations=("spline",), **SMALL)
    no_inputs = copy.deepcopy(slice_data)
    no_inputs.inputs, no_inputs.input_names = None, []
    with pytest.raises(TrainingFitError, match="with_inputs"):
        run_training_fit_talc(no_inputs, budget, with_inputs=True, **SMALL)
    with pytest.raises(TrainingFitError, match="load_probing"):
        run_training_fit_talc(no_inputs, budget, load_probing=True, **SMALL)
