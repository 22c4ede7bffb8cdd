"""Many recordings as one data set: sources, manifests, folds, pooled figures (the split grammar
is tested with it, in thermal_comp_common/test/test_run_splits.py)."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.datasets import DatasetError, RunFold, fold_data, load_runs, resolve_runs, run_splits, segments
from thermal_eval.datasets.evaluate_runs import ChosenParams, evaluate_runs
from thermal_eval.datasets.runs import train_data
from thermal_eval.evaluate.cli import main
from thermal_eval.evaluate.open_loop_models import MODELS
from thermal_eval.evaluate.baselines import BASELINES
from thermal_eval.evaluate.run import evaluate

LAGGED = next(m for m in MODELS if m.name == "lagged_ridge")


def _write_run(path, seed: int, hours: float = 5.0, offset_um: float = 0.0, extra: str | None = None):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 120.0)
    amb = 20.0 + rng.normal() + np.sin(t / 7200.0 + seed)
    slow = amb.copy()
    for i in range(1, t.size):                       # a 40-min lag of the hall temperature
        slow[i] = slow[i - 1] + (amb[i] - slow[i - 1]) * 120.0 / 2400.0
    z = offset_um + 3.0 * (slow - slow[0]) + 0.05 * rng.normal(size=t.size)
    cols = {"amb_c": amb, "slow_c": slow, "z_um": z}
    if extra:
        cols[extra] = amb
    write_recording_csv(path, t, cols)
    return path


@pytest.fixture()
def folder(tmp_path):
    d = tmp_path / "runs"
    for k in range(5):
        _write_run(d / f"day{k}.csv", k, offset_um=10.0 * k)
    return d


def test_sources_files_folder_glob_and_manifests(folder, tmp_path):
    assert [r.name for r in resolve_runs([str(folder)])] == [f"day{k}" for k in range(5)]
    assert [r.name for r in resolve_runs([str(folder / "day[01].csv"), str(folder / "day4.csv")])] == \
        ["day0", "day1", "day4"]
    y = tmp_path / "m.yaml"
    y.write_text("runs:\n  - {path: runs/day0.csv, unit: U1, programme: warm-up, date: 2026-01-02, "
                 "hall_setpoint_c: 21}\n  - {path: runs/day1.csv, unit: U2, date: 2026-01-01}\n")
    runs = resolve_runs([str(y)])
    assert (runs[0].unit, runs[0].programme, runs[0].date, runs[0].hall_setpoint_c) == ("U1", "warm-up", "2026-01-02", 21.0)
    c = tmp_path / "m.csv"
    c.write_text("path,unit,shift\nruns/day2.csv,U1,night\nruns/day3.csv,U3,day\n")
    runs = resolve_runs([str(c)])
    assert [r.unit for r in runs] == ["U1", "U3"] and runs[0].extra == {"shift": "night"}


def test_a_folder_with_its_manifest_gives_the_manifests_runs_and_a_glob_skips_the_manifest(folder):
    (folder / "manifest.csv").write_text("path,unit\nday3.csv,U2\nday1.csv,U1\n")
    runs = resolve_runs([str(folder)])
    assert [(r.name, r.unit) for r in runs] == [("day3", "U2"), ("day1", "U1")]
    assert [r.name for r in resolve_runs([str(folder / "*.csv")])] == [f"day{k}" for k in range(5)]
    (folder / "other.csv").write_text("path\nday0.csv\n")
    with pytest.raises(DatasetError, match="folder holds 2 manifests \\(manifest.csv, other.csv\\)"):
        resolve_runs([str(folder)])


@pytest.mark.parametrize("row, words", [
    ("{unit: U1}", ["runs[0]", "'path'"]),
    ("{path: runs/nope.csv}", ["runs[0]", "'path'", "nope.csv"]),
    ("{path: runs/day0.csv, date: 2026-13-01}", ["'date'", "2026-13-01"]),
    ("{path: runs/day0.csv, hall_setpoint_c: warm}", ["'hall_setpoint_c'", "'warm'"]),
])
def test_a_bad_manifest_entry_is_one_line_naming_file_field_and_value(folder, tmp_path, row, words):
    y = tmp_path / "bad.yaml"
    y.write_text(f"runs:\n  - {row}\n")
    with pytest.raises(DatasetError) as e:
        resolve_runs([str(y)])
    msg = str(e.value)
    assert "\n" not in msg and str(y) in msg and all(w in msg for w in words)


def test_duplicate_files_and_names_are_refused(folder):
    with pytest.raises(DatasetError, match="listed twice"):
        resolve_runs([str(folder / "day0.csv"), str(folder / "day0.csv")])
    with pytest.raises(DatasetError, match="matches no file"):
        resolve_runs([str(folder / "x*.csv")])


def test_each_run_keeps_its_start_reference_and_the_fold_starts_its_clock_at_the_held_out_run(folder):
    runs = load_runs(resolve_runs([str(folder)]))
    assert all(r.data.displacement_um["z_um"][0] == 0.0 and r.data.time_s[0] == 0.0 for r in runs)
    d = fold_data(runs, [0, 1, 2], 4)
    n0 = sum(len(runs[i].data) for i in (0, 1, 2))
    assert d.split.n_train == n0 + 1 and d.split.test == slice(n0 + 1, len(d)) and d.split.validation.stop == len(d)
    assert np.all(np.diff(d.time_s) > 0)
    assert d.displacement_um["z_um"][n0] == 0.0            # the held-out run's start reference closes calibration
    np.testing.assert_array_equal(d.displacement_um["z_um"][n0:], runs[4].data.displacement_um["z_um"])
    parts = segments(runs[0], 3)
    assert len(parts) == 3 and all(p.data.displacement_um["z_um"][0] == 0.0 for p in parts)
    assert sum(len(p.data) for p in parts) == len(runs[0].data) and parts[1].entry.name == "day0#2"


def test_runs_with_other_columns_are_refused_naming_the_file(folder):
    odd = _write_run(folder / "day9.csv", 9, extra="door_open")
    with pytest.raises(DatasetError) as e:
        load_runs(resolve_runs([str(folder)]))
    assert str(odd) in str(e.value) and "inputs" in str(e.value)


def test_pooled_figures_are_the_held_out_runs_rows_together(folder):
    runs = load_runs(resolve_runs([str(folder)]))
    (fold,) = run_splits([r.entry for r in runs], "0.6,0,0.4")
    f = evaluate_runs(runs, [fold], models=BASELINES + [LAGGED], run_start="continued", progress=lambda s: None)
    td = train_data(runs, fold.train)                   # the fold's models are chosen on its training runs alone
    chosen = [replace(m, select=ChosenParams({"z_um": m.select(td, "z_um", len(td))})) for m in BASELINES + [LAGGED]]
    per = [evaluate(fold_data(runs, fold.train, i), models=chosen, show_progress=False) for i in fold.test]
    y = [fold_data(runs, fold.train, i) for i in fold.test]
    ol = [r.open_loop["lagged_ridge"]["z_um"] for r in per]     # scored as the change since the run's start
    res = np.concatenate([d.displacement_um["z_um"][d.split.test] - (p[d.split.test] - p[d.split.n_train - 1])
                          for d, p in zip(y, ol)])
    pooled = f["pooled"]["test"]["open_loop"]["lagged_ridge"]["z_um"]
    assert pooled["mae_um"] == pytest.approx(np.mean(np.abs(res)), abs=1e-3)
    assert pooled["rmse_um"] == pytest.approx(np.sqrt(np.mean(res ** 2)), abs=1e-3)
    assert pooled["n_rows"] == res.size and pooled["runs"] == 2
    base = f["pooled"]["test"]["open_loop"]["static_ls"]["z_um"]["mae_um"]
    assert pooled["ratio_to_static_ls"] == pytest.approx(pooled["mae_um"] / base, abs=2e-3)
    ad = f["pooled"]["test"]["adaptive"]["lagged_ridge"]["z_um"]
    assert ad["ratio_to_hold"] == pytest.approx(ad["mae_um"] / ad["hold_own_probes_mae_um"], abs=2e-3)
    # each held-out run alone is the single-recording evaluation of its fold
    one = f["folds"][0]["per_run"][0]["pooled"]["adaptive"]["lagged_ridge"]["z_um"]["mae_um"]
    assert one == per[0].figures["adaptive"]["lagged_ridge"]["channels"]["z_um"]["mae_test_um"]


def test_cli_on_a_folder_writes_per_run_and_pooled_figures(folder, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main([str(folder), "--out", str(out), "--models", "lagged_ridge", "--no-progress", "--no-rerun",
               "--runs-split", "loro", "--open-loop-only"])
    assert rc == 0
    f = json.loads((out / "evaluation_runs.json").read_text())
    assert len(f["folds"]) == 5 and [r["name"] for r in f["runs"]] == [f"day{k}" for k in range(5)]
    assert f["pooled"]["test"]["open_loop"]["lagged_ridge"]["z_um"]["runs"] == 5
    assert "pooled over 5 held-out test runs" in capsys.readouterr().out
    assert main([str(folder), "--out", str(tmp_path / "o2"), "--runs-split", "by:unit", "--no-progress"]) == 2
    assert "every run has unit = ''" in capsys.readouterr().err


def test_runs_at_rest_start_from_their_first_reading_and_are_never_scored(folder):
    runs = load_runs(resolve_runs([str(folder)]))
    d0 = fold_data(runs, [0, 1, 2], 4)
    d = fold_data(runs, [0, 1, 2], 4, rest_h=1.0)
    k = 30                                               # 1 h at the runs' 120-s step
    assert len(d) == len(d0) + 4 * k and np.all(np.diff(d.time_s) > 0)
    held = runs[4].data
    assert d.split.test.stop - d.split.test.start == len(held) - 1       # the held-out run's own rows only
    np.testing.assert_array_equal(d.displacement_um["z_um"][d.split.test], held.displacement_um["z_um"][1:])
    first = d.split.n_train - 1 - k                      # the held-out run's rest rows repeat its first reading
    np.testing.assert_array_equal(d.temperatures[first:d.split.n_train], np.repeat(held.temperatures[:1], k + 1, 0))
    with pytest.raises(DatasetError, match="rest hours"):
        fold_data(runs, [0, 1, 2], 4, rest_h=-1.0)


def test_temperatures_from_the_runs_start_let_a_static_map_fit_every_run(folder):
    """Runs start at different hall temperatures and their displacements at 0: with each run's
    temperatures relative to its first reading too (separate runs), a least-squares map of the
    temperature changes predicts a held-out run to its noise; absolute temperatures leave an
    offset per run."""
    runs = load_runs(resolve_runs([str(folder)]))
    static = next(m for m in BASELINES if m.name == "static_ls")
    fold = RunFold("f", (0, 1, 2), (), (3, 4))
    rel = evaluate_runs(runs, [fold], models=[static], adaptive=False, run_start="separate", rest_h=0.0,
                        progress=lambda s: None)
    absolute = evaluate_runs(runs, [fold], models=[static], adaptive=False, run_start="continued",
                             progress=lambda s: None)
    assert rel["pooled"]["test"]["open_loop"]["static_ls"]["z_um"]["mae_um"] < 0.1
    assert absolute["pooled"]["test"]["open_loop"]["static_ls"]["z_um"]["mae_um"] > 0.5
    d = fold_data(runs, [0, 1, 2], 4, temperatures_from_start=True)
    held = runs[4].data
    np.testing.assert_allclose(d.temperatures[d.split.test], held.temperatures[1:] - held.temperatures[:1])
