"""The init twin's soft sensors as an ``evaluate`` model: the candidate (the twin's own channel plus
a level, or a ridge on its channel and nodes) is chosen on the training rows only, no held-out
displacement reaches a prediction, and the comparison names the best data-only adaptive row per
channel on the phase mean."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_eval.evaluate.spec import EvaluationData, Split
from thermal_eval.twin_init.fl_adaptive import NAME, channel_features, comparison, twin_model


def _data(y: np.ndarray) -> EvaluationData:
    n = y.size
    t = np.arange(n) * 60.0
    return EvaluationData(t, np.zeros((n, 1)), ["t1"], None, [], {"ch1": y},
                          Split(int(0.6 * n), slice(int(0.8 * n), n), slice(int(0.6 * n), int(0.8 * n)), n), "synthetic")


def _features(n: int = 3000, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    node = np.sin(2 * np.pi * t / 40000.0) + 0.3 * np.sin(2 * np.pi * t / 9000.0)
    twin_out = 2.0 * np.cos(2 * np.pi * t / 30000.0)
    return t, node, twin_out, rng


def test_a_displacement_the_nodes_explain_chooses_the_ridge_and_reads_no_held_out_row():
    _, node, twin_out, rng = _features()
    y = 4.0 * node + 0.2 * twin_out + rng.normal(0, 0.05, node.size)
    feats = channel_features(node[:, None], {"ch1_um": twin_out}, ["ch1"])
    model, data = twin_model(feats), _data(y)
    n_train = data.split.n_train
    params = model.select(data, "ch1", n_train)
    assert params["alpha"] is not None and params["walk_forward_mae_um"] < 0.2
    p = model.predict(data, "ch1", params, n_train)
    assert np.mean(np.abs(p[n_train:] - y[n_train:])) < 0.2
    poisoned = y.copy()
    poisoned[n_train:] = 1e6
    bad = _data(poisoned)
    assert model.select(bad, "ch1", n_train) == params
    np.testing.assert_array_equal(model.predict(bad, "ch1", params, n_train), p)


def test_the_twins_own_channel_plus_a_level_is_chosen_when_it_is_the_displacement():
    _, node, twin_out, rng = _features(seed=1)
    y = twin_out + 5.0 + rng.normal(0, 0.01, node.size)
    model, data = twin_model(channel_features(node[:, None], {"ch1_um": twin_out}, ["ch1"])), _data(y)
    params = model.select(data, "ch1", data.split.n_train)
    assert params["alpha"] is None and set(params["candidates"]) >= {"level", "ridge 1"}
    np.testing.assert_allclose(model.predict(data, "ch1", params, data.split.n_train), twin_out + 5.0, atol=0.01)


def _cell(test: float, val: float, hold: float = 3.0) -> dict:
    mean = {"mae_test_um": test, "mae_validation_um": val, "hold_own_probes_mae_test_um": hold,
            "hold_own_probes_mae_validation_um": hold}
    return {"mae_test_um": test + 1, "mae_validation_um": val + 1, "phases": {"mean": mean}}


def _row(cells: dict, per_h=(0.97, 0.92)) -> dict:
    return {"channels": cells, "probe_phases": {"probings_per_h_after_calibration": list(per_h)}}


def test_the_comparison_names_evaluates_best_row_and_the_best_of_each_channel_on_the_phase_mean():
    ol = {n: {"channels": {c: {"mae_test_um": 5.0, "mae_validation_um": 6.0, "params": {"alpha": None}}
                           for c in ("ch1", "ch2")}} for n in ("train_mean", "static_ls", "lagged_ridge", NAME)}
    figures = {"channels": ["ch1", "ch2"], "open_loop": ol, "adaptive": {
        NAME: _row({"ch1": _cell(1.0, 1.0), "ch2": _cell(2.0, 2.0)}),
        "a": _row({"ch1": _cell(1.2, 0.9), "ch2": _cell(1.5, 1.5)}),      # worst channel 1.5: evaluate's best
        "b": _row({"ch1": _cell(1.5, 1.5), "ch2": _cell(1.9, 1.0)}),
        "broken": {"failed": "diverged", "channels": {}},
        "half": _row({"ch1": {"failed": "no open-loop prediction"}, "ch2": _cell(0.1, 0.1)})}}
    out = comparison(figures)
    assert out["best data-only row"] == "a"
    ch1, ch2 = out["channels"]["ch1"], out["channels"]["ch2"]
    assert ch1["best of the channel"] == "a" and ch2["best of the channel"] == "b"    # 'half' failed on ch1
    assert ch1["best data-only adaptive (a)"] == [1.2, 0.9] and ch2["best data-only adaptive of the channel"] == [1.9, 1.0]
    assert ch1["holding"] == [3.0, 3.0] and ch1["twin open loop"] == [5.0, 6.0]
    assert out["better_than_best_row"] == {"mean_of_windows": 1, "test": 1, "validation": 0}
    assert out["better_than_best_of_each_channel"] == {"mean_of_windows": 1, "test": 1, "validation": 0}
    assert out["better_than_each_row"] == {"a": 1, "b": 1}
    assert out["probings_per_h"][NAME] == pytest.approx(0.97)
