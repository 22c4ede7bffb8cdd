"""thermal-comp evaluate on small synthetic recordings: columns, units, split, failures, outputs, honesty."""
from __future__ import annotations

import json

import numpy as np
import pytest

from synthetic_recording import synthetic, write_csv
from thermal_eval.evaluate.adaptive import ProbingBudget, probe_schedule, run_adaptive
from thermal_eval.evaluate.cli import main
from thermal_eval.evaluate.run import available_models, evaluate
from thermal_eval.evaluate.spec import SpecError, evaluation_data, load_evaluation_data, make_split
from thermal_eval.evaluate.model_selection import ModelSpec, out_of_fold_prediction
from thermal_eval.evaluate.open_loop_models import MODELS
from thermal_comp_common.recording_csv import Recording

LAGGED = next(m for m in MODELS if m.name == "lagged_ridge")


@pytest.fixture()
def csv_path(tmp_path):
    p = tmp_path / "rec.csv"
    write_csv(p, synthetic(), bom=True)
    return p


def _data(**kw):
    cols = synthetic(**kw)
    rec = Recording(cols.pop("time_s"), cols)
    return evaluation_data(rec, {})


def test_default_columns_by_kind_and_the_split_in_time_order():
    d = _data()
    assert d.sensors == ["t_fast_c", "t_slow_c", "ambient_c"] and d.channels == ["z_um", "x_um"]
    assert d.input_names == ["spindle_rpm"]
    assert (d.split.n_train, d.split.validation, d.split.test) == (540, slice(540, 720), slice(720, 900))
    s = make_split(900, {"order": ["test", "validation"]})
    assert s.test == slice(540, 720) and s.validation == slice(720, 900)
    s = make_split(900, {"train_end": 600, "held_out_boundary": 800})
    assert (s.n_train, s.validation, s.test) == (600, slice(600, 800), slice(800, 900))


def test_a_missing_column_is_named_with_its_closest_match(csv_path):
    with pytest.raises(SpecError, match=r"'z_mm'.*closest: 'z_um'"):
        load_evaluation_data(csv_path, {"displacements": ["z_mm"]})
    with pytest.raises(SpecError, match=r"spliit.*closest: 'split'"):
        load_evaluation_data(csv_path, {"spliit": {}})
    with pytest.raises(SpecError, match="fractions"):
        make_split(100, {"train": 0.9, "validation": 0.2, "test": 0.2})


def test_mapping_globs_and_units(tmp_path):
    cols = synthetic()
    p = tmp_path / "logger.csv"
    write_csv(p, cols, rename={"z_um": "Z_axial", "t_fast_c": "T_front", "t_slow_c": "T_rear"})
    d = load_evaluation_data(p, {"temperatures": ["T_*"], "displacements": ["Z_axial"], "units": {"Z_axial": "mm"}})
    assert d.sensors == ["T_front", "T_rear"] and d.channels == ["Z_axial"]
    z = cols["z_um"]
    assert np.allclose(d.displacement_um["Z_axial"], (z - z[0]) * 1000.0, atol=0.2)
    d2 = load_evaluation_data(p, {"temperatures": ["T_front"]}, map_flags=["Z_axial=z_um", "z_um*-1"])
    assert d2.channels == ["z_um", "x_um"] and np.allclose(d2.displacement_um["z_um"], -(z - z[0]), atol=1e-4)


def test_a_failing_model_is_one_row_with_its_reason_and_the_others_stay():
    def boom(data, ch, params, n_fit):
        raise np.linalg.LinAlgError("singular matrix")
    broken = ModelSpec("broken", "model", "always fails", lambda d, c, n: {}, boom)
    diverged = ModelSpec("diverged", "model", "blows up", lambda d, c, n: {},
                         lambda d, c, p, n: np.full(len(d), np.inf))
    d = _data()
    res = evaluate(d, models=[broken, diverged, LAGGED], show_progress=False)
    ol = res.figures["open_loop"]
    assert "LinAlgError: singular matrix" in ol["broken"]["channels"]["z_um"]["failed"]
    assert "diverged" in ol["diverged"]["channels"]["x_um"]["failed"]
    assert ol["lagged_ridge"]["channels"]["z_um"]["mae_test_um"] < 1.0
    assert res.figures["adaptive"]["broken"]["failed"]
    assert "mae_test_um" in res.figures["adaptive"]["lagged_ridge"]["channels"]["z_um"]


def test_adaptive_sees_only_the_training_rows_and_its_own_probes():
    d = _data()
    model = LAGGED
    params = {ch: model.select(d, ch, d.split.n_train) for ch in d.channels}
    pred = {ch: model.predict(d, ch, params[ch], d.split.n_train) for ch in d.channels}
    oof = {ch: out_of_fold_prediction(model, d, ch, params[ch], d.split.n_train) for ch in d.channels}
    budget = ProbingBudget(probe_every_h=2.0, max_probes_per_h=1.0, tolerance_um=0.5)
    a = run_adaptive(d, pred, oof, budget)
    keep = np.zeros(len(d), bool)
    keep[:d.split.n_train] = True
    keep[a.probe_rows] = True
    for ch in d.channels:   # poison every displacement the model may not see
        d.displacement_um[ch] = np.where(keep, d.displacement_um[ch], 1e6)
    b = run_adaptive(d, pred, oof, budget)
    assert b.probe_rows == a.probe_rows
    for ch in d.channels:
        assert np.array_equal(a.compensation[ch][d.split.n_train:], b.compensation[ch][d.split.n_train:])


def test_probings_stay_within_the_budget_and_the_model_asks_for_some():
    d = _data()
    pred = {"z_um": d.displacement_um["z_um"] * 0 + np.sin(np.arange(len(d)) / 5.0) * 10}  # changes all the time
    budget = ProbingBudget(probe_every_h=5.0, max_probes_per_h=1.0, tolerance_um=1.0)
    rows, asked = probe_schedule(d, pred, budget)
    t = d.time_s
    start = d.split.n_train
    for i, r in enumerate(rows):   # at every probing, the count so far is within rate x elapsed + 1
        assert i + 1 <= (t[r] - t[start - 1]) / 3600.0 + 1e-9
    assert asked and len(rows) <= (t[-1] - t[start - 1]) / 3600.0


def test_a_useless_model_is_never_clearly_worse_than_holding_its_probes():
    d = _data(plateau=True)
    rng = np.random.default_rng(1)
    noise = ModelSpec("noise", "model", "random", lambda d, c, n: {},
                      lambda d, c, p, n: np.random.default_rng(2).normal(0, 2.0, len(d)))
    res = evaluate(d, models=[noise], show_progress=False)
    for ch, c in res.figures["adaptive"]["noise"]["channels"].items():
        assert c["model_weight"] < 0.1
        assert c["mae_test_um"] <= 1.1 * c["hold_own_probes_mae_test_um"] + 0.05
    del rng


def test_cli_writes_table_json_png_rrd_and_refuses_a_non_empty_out(csv_path, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main([str(csv_path), "--out", str(out), "--models", "lagged_ridge", "--no-progress"])
    assert rc == 0
    f = json.loads((out / "evaluation.json").read_text())
    assert set(f["open_loop"]) == {"train_mean", "hold_last_training", "static_ls", "lowpass_ridge", "lagged_ridge"}
    z = f["open_loop"]["lagged_ridge"]["channels"]["z_um"]
    assert f["ratio_baseline"] == "static_ls"
    base = f["open_loop"]["static_ls"]["channels"]["z_um"]
    assert z["ratio_to_static_ls_test"] == pytest.approx(z["mae_test_um"] / base["mae_test_um"], rel=1e-2)
    assert all(z[f"{k}_{w}_um"] is not None for k in ("mae", "rmse", "p99") for w in ("test", "validation"))
    assert z["mae_test_um"] <= z["rmse_test_um"] <= z["p99_test_um"] + 1e-9
    ad = f["adaptive"]["lagged_ridge"]
    assert ad["probings_after_calibration"] >= 1 and "hold_own_probes_mae_test_um" in ad["channels"]["x_um"]
    assert (out / "evaluation.png").stat().st_size > 0 and (out / "evaluation.rrd").stat().st_size > 0
    assert "hold lagged_ridge's probes" in capsys.readouterr().out
    assert main([str(csv_path), "--out", str(out), "--no-progress"]) == 3
    assert main([str(csv_path), "--out", str(tmp_path / "o2"), "--displacements", "zz_um", "--no-progress"]) == 2
    assert "closest: 'z_um'" in capsys.readouterr().err


def test_models_needing_inputs_are_left_out_without_inputs():
    d = _data()
    assert any(m.needs_inputs for m in available_models(d))
    d.inputs, d.input_names = None, []
    assert not any(m.needs_inputs for m in available_models(d))
    with pytest.raises(SpecError, match="closest: 'lagged_ridge'"):
        available_models(d, ["lagged_rige"])


def test_the_static_gp_is_opt_in():
    d = _data()
    names = [m.name for m in available_models(d)]
    assert "gp_static" not in names and "lagged_ridge_gain_update" not in names and "lagged_ridge" in names
    also = [m.name for m in available_models(d, also=["gp_static"])]
    assert also == names + ["gp_static"]


def _arrays_equal(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[m].keys() == b[m].keys() and all(np.array_equal(a[m][c], b[m][c], equal_nan=True) for c in a[m]) for m in a)


def test_model_rows_on_a_local_pool_give_the_serial_figures():
    from thermal_comp_common.runtime.task_engine import EngineSpec
    d = _data()
    models = available_models(d, ["lagged_ridge", "arx_subgrid"])
    serial = evaluate(d, models=models, show_progress=False)
    pooled = evaluate(d, models=models, show_progress=False, engine=EngineSpec("local", workers=2))
    for f in (serial.figures, pooled.figures):
        f.pop("seconds"), f.pop("engine")
        for kind in ("open_loop",):
            for row in f[kind].values():
                row.pop("seconds")
    assert list(pooled.figures["open_loop"]) == [m.name for m in models]
    assert serial.figures == pooled.figures
    assert _arrays_equal(serial.open_loop, pooled.open_loop) and _arrays_equal(serial.adaptive, pooled.adaptive)
    assert serial.probe_rows == pooled.probe_rows


def test_the_project_adaptive_models_run_their_own_logic_within_the_budget():
    from thermal_eval.evaluate.model_rows import hold_probes
    d = _data()
    res = evaluate(d, models=available_models(d, ["lagged_ridge"]), show_progress=False,
                   closed_loop=["agp_closed_loop", "talc_closed_loop"])
    agp = res.figures["adaptive"]["agp_closed_loop"]
    assert agp["kind"] == "closed_loop" and agp["calibration_end_h"] is not None
    hours = (d.time_s[-1] - d.time_s[0]) / 3600.0 - agp["calibration_end_h"]
    assert 1 <= agp["probings_after_calibration"] <= hours          # the cap: 1 per hour after calibration
    assert agp["steps_probing_refused_by_budget"] > 0 and agp["recalibrations"] >= 1
    rows = res.probe_rows["agp_closed_loop"]
    for ch in d.channels:     # beside it: holding exactly its probes
        assert np.array_equal(res.hold["agp_closed_loop"][ch], hold_probes(d.displacement_um[ch], rows, len(d)),
                              equal_nan=True)
        assert agp["channels"][ch]["ratio_to_hold_test"] < 1.0
    assert "talc_closed_loop" in res.figures["adaptive"]
    with pytest.raises(SpecError, match="closest: 'agp_closed_loop'"):
        evaluate(d, models=[], show_progress=False, closed_loop=["agp_closedloop"])


def test_the_hold_beside_a_model_is_pure_holding_of_its_probes():
    d = _data()
    model = LAGGED
    params = {ch: model.select(d, ch, d.split.n_train) for ch in d.channels}
    pred = {ch: model.predict(d, ch, params[ch], d.split.n_train) for ch in d.channels}
    oof = {ch: out_of_fold_prediction(model, d, ch, params[ch], d.split.n_train) for ch in d.channels}
    a = run_adaptive(d, pred, oof, ProbingBudget(probe_every_h=2.0, max_probes_per_h=1.0, tolerance_um=0.5))
    measured = [d.split.n_train - 1] + a.probe_rows
    for ch in d.channels:
        y, h = d.displacement_um[ch], a.hold[ch]
        for r in range(d.split.n_train, len(d)):     # a probe row was compensated before its probe
            last = max(m for m in measured if m < r)
            assert h[r] == y[last]


def test_the_lagged_ridge_gain_update_chooses_its_penalty_on_the_training_rows():
    from thermal_eval.evaluate.run import REGISTRY, model_row
    d = _data()
    row = model_row(d, REGISTRY["lagged_ridge_gain_update"], True, ProbingBudget())
    for ch in d.channels:
        info = row.open_loop["channels"][ch]["probe_gain_update"]
        assert info["walk_forward_rows"][1] == d.split.n_train
        assert info["penalty"] == min(map(float, info["walk_forward_mae_um"]),
                                      key=lambda v: info["walk_forward_mae_um"][f"{v:g}"])
        assert np.isfinite(row.compensation[ch][d.split.n_train:]).all()
