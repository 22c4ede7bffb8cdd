"""Characteristic diagrams: smoothed grid regression, load-case update, input selection."""
from __future__ import annotations

import json

import numpy as np
import pytest

from talc_model.cd.input_selection import StabilityIndex, forward_selection, stability_selection
from talc_model.cd.measurement_update import measurement_update
from talc_model.cd.diagram import (CharacteristicDiagram, CharacteristicDiagramError,
                                               fit_with_grid_refinement, load_case_update, second_difference_operator)
from thermal_comp_common.metrics import rmse


def smooth(u):
    return np.sin(2.0 * u[:, 0]) + 0.5 * u[:, 1] ** 2


def test_diagram_reproduces_a_known_smooth_function():
    rng = np.random.default_rng(0)
    u = rng.uniform(0, 1, (400, 2))
    cd = CharacteristicDiagram(n_intervals=8, smoothing=1e-4).fit(u, smooth(u) + rng.normal(0, 0.01, 400))
    ut = rng.uniform(0, 1, (300, 2))
    assert rmse(cd.predict(ut), smooth(ut)) < 0.02
    # a multilinear function is reproduced exactly (it lies in the smoothing null space)
    bil = lambda v: 1.0 + 2.0 * v[:, 0] - 3.0 * v[:, 1] + 0.5 * v[:, 0] * v[:, 1]
    cd2 = CharacteristicDiagram(n_intervals=4, smoothing=1.0, bounds=([0, 0], [1, 1])).fit(u, bil(u))
    np.testing.assert_allclose(cd2.predict(ut), bil(ut), atol=1e-5)


def test_smoothing_fills_empty_cells_and_grid_refinement_stops():
    rng = np.random.default_rng(1)
    u = rng.uniform(0, 1, (300, 1))
    u = u[(u[:, 0] < 0.4) | (u[:, 0] > 0.6)]                       # a gap without data
    f = lambda v: np.sin(3.0 * v[:, 0])
    cd = CharacteristicDiagram(n_intervals=20, smoothing=1e-5).fit(u, f(u))
    gap = np.linspace(0.42, 0.58, 9)[:, None]
    assert np.max(np.abs(cd.predict(gap) - f(gap))) < 0.05
    ut = rng.uniform(0, 1, (200, 1))
    best, hist = fit_with_grid_refinement(u, f(u), ut, f(ut), max_intervals=64)
    assert [h["n_intervals"] for h in hist][:3] == [1, 2, 4]
    assert hist[-1]["n_intervals"] < 64 or len(hist) == 7
    assert rmse(best.predict(ut), f(ut)) == pytest.approx(min(h["val_rmse"] for h in hist))


def test_data_weights_pull_the_fit_towards_heavy_samples():
    u = np.array([[0.0], [0.5], [0.5], [1.0]])
    y = np.array([0.0, 1.0, 0.0, 0.0])
    even = CharacteristicDiagram(n_intervals=2, smoothing=0.0).fit(u, y)
    heavy = CharacteristicDiagram(n_intervals=2, smoothing=0.0).fit(u, y, sample_weight=[1, 9, 1, 1])
    assert even.predict([[0.5]])[0] == pytest.approx(0.5, abs=1e-6)
    assert heavy.predict([[0.5]])[0] == pytest.approx(0.9, abs=1e-6)


def test_out_of_grid_inputs_are_clamped_and_counted_and_state_round_trips():
    rng = np.random.default_rng(2)
    u = rng.uniform(0, 1, (100, 2))
    cd = CharacteristicDiagram(n_intervals=3).fit(u, smooth(u))
    lo, hi = cd.lower_, cd.upper_
    edge = cd.predict([[hi[0], hi[1]]])
    assert cd.predict([[hi[0] + 5, hi[1] + 5]])[0] == pytest.approx(edge[0])
    assert cd.out_of_range_count_ == 1
    back = CharacteristicDiagram.from_state(json.loads(json.dumps(cd.to_state())))
    ut = rng.uniform(0, 1, (50, 2))
    np.testing.assert_allclose(back.predict(ut), cd.predict(ut))
    assert np.isnan(cd.predict([[np.nan, 0.5]])[0])


def test_extrapolating_inputs_continue_the_boundary_cell_linearly_the_others_clamp():
    rng = np.random.default_rng(3)
    u = rng.uniform(0, 1, (200, 2))
    lin = lambda v: 2.0 + 3.0 * v[:, 0] - 1.0 * v[:, 1]            # in the smoothing null space: exact
    cd = CharacteristicDiagram(n_intervals=4, smoothing=1.0, bounds=([0, 0], [1, 1]), extrapolate=[True, False])
    cd.fit(u, lin(u))
    out = np.array([[3.0, 0.5], [-2.0, 0.5], [0.5, 4.0]])
    np.testing.assert_allclose(cd.predict(out[:2]), lin(out[:2]), atol=1e-5)   # along input 0: the line
    assert cd.predict(out[2:])[0] == pytest.approx(lin(np.array([[0.5, 1.0]]))[0], abs=1e-5)   # input 1 clamps
    assert cd.out_of_range_count_ == 3
    back = CharacteristicDiagram.from_state(json.loads(json.dumps(cd.to_state())))
    assert back.to_state()["extrapolate"] == [True, False]
    np.testing.assert_allclose(back.predict(out), cd.predict(out))
    old = {k: v for k, v in cd.to_state().items() if k != "extrapolate"}     # saved before the option: clamps
    assert CharacteristicDiagram.from_state(old).predict(out[:1])[0] == pytest.approx(lin(np.array([[1.0, 0.5]]))[0],
                                                                                      abs=1e-5)


def test_bad_input_names_the_argument():
    cd = CharacteristicDiagram()
    with pytest.raises(CharacteristicDiagramError, match="y: 3 values for 4 samples"):
        cd.fit(np.zeros((4, 2)), np.zeros(3))
    with pytest.raises(CharacteristicDiagramError, match="sample_weight"):
        cd.fit(np.zeros((4, 1)), np.zeros(4), sample_weight=[1, -1, 1, 1])
    with pytest.raises(CharacteristicDiagramError, match="n_intervals"):
        CharacteristicDiagram(n_intervals=[2, 3, 4]).fit(np.zeros((4, 2)), np.zeros(4))
    with pytest.raises(CharacteristicDiagramError, match="not fitted"):
        CharacteristicDiagram().predict([[0.0]])
    assert second_difference_operator((4, 3), 0).shape == (2 * 3, 12)


def test_load_case_update_moves_the_diagram_towards_new_data_with_weight_decay():
    rng = np.random.default_rng(3)
    u = rng.uniform(0, 1, (400, 2))
    y = smooth(u) + rng.normal(0, 0.01, 400)
    base = CharacteristicDiagram(n_intervals=4).fit(u, y)
    # new load case: partly outside the trained range, where the base model extrapolates badly
    un = np.column_stack([rng.uniform(0.9, 1.5, 120), rng.uniform(0, 1, 120)])
    g = lambda v: smooth(v) + 0.5 * np.clip(v[:, 0] - 1.0, 0, None)
    yn = g(un) + rng.normal(0, 0.01, 120)
    res = load_case_update(base.predict, u, y, un, yn, make_cd=lambda: CharacteristicDiagram(n_intervals=6))
    assert res.accepted
    before = rmse(base.predict(un), yn)
    updated = base.predict(un) + res.update.predict(un)
    assert rmse(updated, yn) < 0.25 * before
    assert rmse(updated, yn) <= 2 * res.rmse_reference + 1e-12
    # the original load case is barely disturbed
    assert rmse(base.predict(u) + res.update.predict(u), y) < 0.05
    # the loop: w_new 10, 7, 4.9, ... until the new-data RMSE exceeds twice the reference
    ws = [it["w_new"] for it in res.iterations]
    np.testing.assert_allclose(ws, 10.0 * 0.7 ** np.arange(len(ws)))
    assert res.iterations[-1]["rmse_new"] > 2 * res.rmse_reference
    assert all(it["rmse_new"] <= 2 * res.rmse_reference for it in res.iterations[:-1])
    assert res.w_new == pytest.approx(ws[-2])
    # decaying the new-data weight trades new-data fit for original-data fit
    new_err = [it["rmse_new"] for it in res.iterations]
    assert all(b >= a - 1e-9 for a, b in zip(new_err, new_err[1:]))


def test_load_case_update_falls_back_to_the_reference_when_no_weight_is_acceptable():
    rng = np.random.default_rng(4)
    u = rng.uniform(0, 1, (300, 1))
    base = CharacteristicDiagram(n_intervals=4).fit(u, np.sin(3 * u[:, 0]))
    # same inputs, contradicting outputs: the union cannot fit the new data within 2x
    res = load_case_update(base.predict, u, np.sin(3 * u[:, 0]), u[:50], np.sin(3 * u[:50, 0]) + 1.0,
                           make_cd=lambda: CharacteristicDiagram(n_intervals=4))
    assert not res.accepted and len(res.iterations) == 1


def _selection_data(seed: int, k: int = 150, p: int = 8):
    rng = np.random.default_rng(seed)
    m = rng.uniform(0, 1, (k, p))
    y = np.sin(3.0 * m[:, 2]) + m[:, 5] ** 2 + rng.normal(0, 0.02, k)
    return m, y


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_selection_picks_the_truly_relevant_inputs(seed):
    m, y = _selection_data(seed)
    steps = forward_selection(m, y, max_inputs=3, make_cd=lambda: CharacteristicDiagram(n_intervals=4))
    assert set(steps[1].subset) == {2, 5}
    assert steps[1].score < 0.5 * steps[0].score
    # a third, irrelevant input brings no real gain: the search stops or barely improves
    assert len(steps) == 2 or steps[2].score > 0.8 * steps[1].score
    full = forward_selection(m, y, max_inputs=3, min_relative_gain=-np.inf,
                             make_cd=lambda: CharacteristicDiagram(n_intervals=4))
    assert len(full) == 3 and full[2].score > 0.8 * full[1].score


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stability_index_picks_the_truly_relevant_inputs(seed):
    m, y = _selection_data(seed)
    steps = stability_selection(m, y, max_inputs=4, exhaustive_up_to=2)
    assert set(steps[1].subset) == {2, 5}
    assert {2, 5} <= set(steps[3].subset)          # the remove-1-add-2 step keeps them
    si = StabilityIndex(m, y)
    assert si.index((2, 5)) < si.index((0, 1))
    with pytest.raises(CharacteristicDiagramError, match="variant"):
        StabilityIndex(m, y, variant="other")


def test_measurement_update_moves_support_points_towards_the_measured_field():
    rng = np.random.default_rng(5)
    grid = np.array([[x, y, z] for x in (0.0, 400.0, 800.0) for y in (0.0, 325.0, 650.0)
                     for z in (0.0, 275.0, 550.0)])                      # 27 support points
    meas_xyz = np.array([[x, y, 50.0] for x in (100.0, 300.0, 500.0, 700.0) for y in (100.0, 300.0, 500.0)])
    k = 40
    temps = rng.uniform(20.0, 30.0, (k, 3))
    dt = temps - 20.0
    field = lambda xyz, d: (0.8 * d[:, [0]] + 0.002 * d[:, [1]] * xyz[None, :, 0]
                            + 0.3 * d[:, [2]] * (xyz[None, :, 2] / 550.0))
    true_support = field(grid, dt)
    base_support = 0.8 * dt[:, [0]] * np.ones((1, 27))     # the base model misses two terms
    measured = field(meas_xyz, dt) + rng.normal(0, 0.05, (k, 12))
    upd = measurement_update(temps, base_support, grid, meas_xyz, measured,
                             make_cd=lambda: CharacteristicDiagram(n_intervals=2, smoothing=1e-4))
    assert upd.rmse_after < 0.3 * upd.rmse_before
    # unseen temperatures: the updated support points near the measured plane approach the truth
    t_new = rng.uniform(21.0, 29.0, (10, 3))
    d_new = t_new - 20.0
    low = grid[:, 2] == 0.0
    base_new = 0.8 * d_new[:, [0]] * np.ones((1, 27))
    err_before = rmse(base_new[:, low], field(grid, d_new)[:, low])
    err_after = rmse((base_new + upd.predict(t_new))[:, low], field(grid, d_new)[:, low])
    assert err_after < 0.5 * err_before
    with pytest.raises(CharacteristicDiagramError, match="measured: shape"):
        measurement_update(temps, base_support, grid, meas_xyz, measured[:, :5])
