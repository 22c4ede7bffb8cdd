"""`thermal-comp calibrate --runs-split`: evaluate's split grammar on several runs, one fit per
fold, every held-out run scored by the fold that did not see it, pooled over the folds, the
parameters' spread across folds, the fit on all runs written; held-out runs never enter a fit."""
from __future__ import annotations

import json
import pathlib
from types import SimpleNamespace

import numpy as np
import pytest

from thermal_twin.calibrate.bounds import Param
from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.fit import Estimate
from thermal_twin.calibrate.runs import calibrate_folds, calibrate_runs, holdout_fold, parameter_spread
from thermal_twin.diagnose.report_check import underived_numbers
from thermal_twin.machine.schema import load_machine
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import write_recording_csv
from thermal_comp_common.recording_sources import RunEntry
from thermal_comp_common.run_splits import run_splits
from moved_mini_mill import SECTION, TRUE, TWIN, moved_runs
from thermal_comp_common.runtime.task_engine import EngineSpec

NAMES = ["a", "b", "c", "d"]
UNITS = ["U1", "U1", "U2", "U2"]


@pytest.fixture(scope="module")
def runs():
    """Four 8 h runs of the moved twin (two per unit)."""
    return moved_runs(4, 8.0, 40)


def _entries(n: int) -> list[RunEntry]:
    return [RunEntry(f"{NAMES[k]}.csv", NAMES[k], unit=UNITS[k]) for k in range(n)]


def _held_out_residuals(rc, channel: str) -> tuple[np.ndarray, np.ndarray]:
    r = rc.result
    return r.measured[channel][r.n_train:], r.after[channel][r.n_train:]


def test_loro_on_three_runs_holds_each_run_out_once_and_pools_the_folds_residuals(runs):
    folds = run_splits(_entries(3), "loro")
    said = []
    fc = calibrate_folds(TWIN, runs[:3], NAMES[:3], folds, section=SECTION, max_nfev=12, progress=said.append)
    assert len(fc.folds) == 3
    held = [name for f in fc.folds for name in f["held_out"]]
    assert sorted(held) == ["a", "b", "c"]
    for f, name in zip(fc.folds, ["a", "b", "c"]):
        assert f["held_out"] == [name] and name not in f["train"]
    # the pooled held-out figure is the RMSE over every fold's held-out residuals laid together
    fits = [calibrate_runs(TWIN, runs[:3], NAMES[:3], section=SECTION, max_nfev=12, fold=f) for f in folds]
    for c in ("E_Z0T", "head_c", "spindle_c"):
        parts = [_held_out_residuals(rc, c) for rc in fits]
        pooled = rmse(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
        assert fc.pooled[c]["rmse_after"] == pytest.approx(pooled, rel=1e-9)
        assert fc.pooled[c]["n"] == sum(p[0].size for p in parts)
        assert fc.pooled[c]["rmse_after"] < 0.3 * fc.pooled[c]["rmse_before"], (c, fc.pooled[c])
    # the twin written is the fit on all runs: every row in sample, both moved parameters found
    assert fc.written_from == "all runs"
    assert fc.written.result.n_train == sum(len(r) for r in runs[:3])
    est = {e.param.path: e.value for e in fc.written.result.estimates}
    for path, v in TRUE.items():
        assert est[path] == pytest.approx(v, rel=0.05), (path, est[path], v)
    assert len(fc.spread) == len(fc.written.result.estimates)
    assert "fold 1/3 (without a): fitting b, c; scoring a" in said
    assert [s.split(" in ")[0] for s in said if " done in " in s] == [f"fold {k}/3 done" for k in (1, 2, 3)] + [
        "all runs done"]
    assert any(s.startswith("all 3 runs: fitting the twin written") for s in said)


def test_folds_on_a_pool_of_two_workers_give_the_serial_answer(runs):
    folds = run_splits(_entries(3), "loro")
    serial = calibrate_folds(TWIN, runs[:3], NAMES[:3], folds, section=SECTION, max_nfev=4)
    said = []
    pooled = calibrate_folds(TWIN, runs[:3], NAMES[:3], folds, section=SECTION, max_nfev=4, progress=said.append,
                             engine=EngineSpec("local", None, 2))
    assert [f["parameters"] for f in pooled.folds] == [f["parameters"] for f in serial.folds]
    assert pooled.pooled == serial.pooled
    assert [e.value for e in pooled.written.result.estimates] == [e.value for e in serial.written.result.estimates]
    assert sorted(s.split(" done")[0] for s in said if " done in " in s) == ["all runs"] + [f"fold {k}/3" for k in (1, 2, 3)]


def test_a_held_out_run_never_enters_the_fit(runs):
    fold = run_splits(_entries(3), "loro")[2]                 # a and b fitted, c held out
    clean = calibrate_runs(TWIN, runs[:3], NAMES[:3], section=SECTION, max_nfev=8, fold=fold)
    bad = runs[2].slice(0, len(runs[2]))
    rng = np.random.default_rng(3)
    bad.columns["E_Z0T"] = bad.columns["E_Z0T"] + 1000.0 * rng.normal(size=len(bad))
    bad.columns["head_c"] = bad.columns["head_c"] + 50.0
    dirty = calibrate_runs(TWIN, [runs[0], runs[1], bad], NAMES[:3], section=SECTION, max_nfev=8, fold=fold)
    assert [e.value for e in dirty.result.estimates] == [e.value for e in clean.result.estimates]
    assert dirty.result.cost_after == clean.result.cost_after
    assert dirty.runs[2]["channels"]["E_Z0T"]["rmse_after"] > 100.0 * clean.runs[2]["channels"]["E_Z0T"]["rmse_after"]


def test_holdout_runs_is_the_named_split_of_the_grammar(runs):
    by_name = calibrate_runs(TWIN, runs[:3], NAMES[:3], section=SECTION, max_nfev=6, holdout="a")
    (fold,) = run_splits(_entries(3), "test=a")
    assert (fold.train, fold.test) == (holdout_fold(NAMES[:3], "a").train, holdout_fold(NAMES[:3], "a").test)
    grammar = calibrate_runs(TWIN, runs[:3], NAMES[:3], section=SECTION, max_nfev=6, fold=fold)
    assert [e.value for e in grammar.result.estimates] == [e.value for e in by_name.result.estimates]
    assert [(x["name"], x["role"]) for x in grammar.runs] == [("b", "train"), ("c", "train"), ("a", "holdout")]


def test_parameter_spread_flags_a_parameter_that_moves_between_folds():
    moving = Param("links.x.conductance", "conductance", ("links", "x", "conductance"), 1.0, 0.5, 2.0, True)
    still = Param("links.y.conductance", "conductance", ("links", "y", "conductance"), 1.0, 0.5, 2.0, True)
    fit = lambda a, b: SimpleNamespace(result=SimpleNamespace(estimates=[
        Estimate(moving, a, (a * 0.95, a * 1.05)), Estimate(still, b, (0.9, 1.1))]))
    spread = parameter_spread([fit(0.6, 1.0), fit(1.8, 1.05)], fit(1.2, 1.02))
    assert [s["name"] for s in spread] == ["links.x.conductance", "links.y.conductance"]
    assert spread[0]["share_of_range"] == pytest.approx(np.log(3.0) / np.log(4.0))
    assert (spread[0]["moves"], spread[0]["disjoint"], spread[0]["written"]) == (True, True, 1.2)
    assert spread[1]["share_of_range"] == pytest.approx(np.log(1.05) / np.log(4.0))
    assert (spread[1]["moves"], spread[1]["disjoint"]) == (False, False)
    assert parameter_spread([fit(0.6, 1.0)], fit(0.6, 1.0)) == []


def _write_manifest(runs, tmp_path) -> pathlib.Path:
    rows = []
    for k, rec in enumerate(runs):
        write_recording_csv(tmp_path / f"{NAMES[k]}.csv", rec.time_s, rec.columns)
        rows.append(f"{NAMES[k]}.csv,{UNITS[k]}\n")
    m = tmp_path / "m.csv"
    m.write_text("path,unit\n" + "".join(rows))
    return m


def test_cli_by_unit_reports_every_fold_and_the_pooled_figure_from_report_json(runs, tmp_path, capsys):
    m = _write_manifest(runs, tmp_path)
    bounds = tmp_path / "bounds.yaml"
    bounds.write_text(json.dumps({"calibration": SECTION}))
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", str(m), "--out", str(out), "--bounds", str(bounds),
                 "--runs-split", "by:unit", "--max-nfev", "6"]) == 0
    cap = capsys.readouterr()
    assert "fold 1/2 (unit=U1): fitting c, d; scoring a, b" in cap.err.splitlines()
    assert "fold 2/2 (unit=U2): fitting a, b; scoring c, d" in cap.err.splitlines()
    assert "held-out runs pooled over folds RMSE" in cap.out and "run a (holdout, fold unit=U1)" in cap.out
    assert "twin written: the fit on all 4 runs" in cap.out
    rep = json.loads((out / "report.json").read_text())
    fo = rep["folds"]
    assert fo["n_folds"] == 2 and fo["written"] == "all runs"
    assert [(f["train"], f["held_out"]) for f in fo["folds"]] == [(["c", "d"], ["a", "b"]), (["a", "b"], ["c", "d"])]
    held = [x for f in fo["folds"] for x in f["runs"] if x["role"] != "train"]
    for c, v in fo["pooled_held_out"].items():
        n = np.array([x["channels"][c]["n"] for x in held])
        e = np.array([x["channels"][c]["rmse_after"] for x in held])
        assert v["rmse_after"] == pytest.approx(np.sqrt(np.sum(n * e ** 2) / n.sum()))
        assert rep["channels"][c]["holdout_rmse_after"] == v["rmse_after"]
    assert rep["split"]["by_run"] == {"train": NAMES, "holdout": []}
    assert {p["name"] for p in fo["parameter_spread"]} == {p["name"] for p in rep["parameters"]}
    md = (out / "report.md").read_text()
    assert "## Folds (2;" in md and "| **pooled** | all folds |" in md and "## Parameters across folds" in md
    assert f"{fo['n_moving']} of {fo['n_parameters']} parameters move" in md
    assert fo["n_parameters"] == len(rep["parameters"]) and fo["n_moving"] == len(fo["moving_parameters"])
    assert underived_numbers(md, rep) == []
    load_machine(out / "twin_calibrated.yaml")


def test_cli_one_fold_with_a_validation_run_writes_that_folds_fit(runs, tmp_path, capsys):
    m = _write_manifest(runs, tmp_path)
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", str(m), "--out", str(out), "--quiet",
                 "--runs-split", "0.5,0.25,0.25", "--max-nfev", "3"]) == 0
    assert "run c (validation)" in capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    assert rep["split"]["fold"] == "0.5,0.25,0.25" and "folds" not in rep
    assert rep["split"]["by_run"] == {"train": ["a", "b"], "holdout": ["d"], "validation": ["c"]}
    assert [x["role"] for x in rep["runs"]] == ["train", "train", "validation", "holdout"]
    assert "| c | validation |" in (out / "report.md").read_text()


@pytest.mark.parametrize("args, words", [
    (["--runs-split", "by:unit=U1,U2"], "runs split 'by:unit=U1,U2': fold unit=U1,U2 leaves no training run"),
    (["--runs-split", "test=a,b,c,d"], "runs split 'test=a,b,c,d': need at least one training run"),
    (["--runs-split", "loro", "--holdout-runs", "1"], "--runs-split loro and --holdout-runs 1: give one split"),
    (["--runs-split", "by:colour"], "field 'colour' is not run metadata"),
])
def test_a_split_that_cannot_be_fitted_is_refused_in_one_line(runs, tmp_path, capsys, args, words):
    m = _write_manifest(runs, tmp_path)
    assert main(["--twin", str(TWIN), "--recording", str(m), "--out", str(tmp_path / "cal"), "--quiet", *args]) == 1
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1, err
    assert not (tmp_path / "cal").exists()


def test_runs_split_with_one_recording_is_refused(runs, tmp_path, capsys):
    write_recording_csv(tmp_path / "one.csv", runs[0].time_s, runs[0].columns)
    assert main(["--twin", str(TWIN), "--recording", str(tmp_path / "one.csv"), "--out", str(tmp_path / "cal"),
                 "--quiet", "--runs-split", "loro"]) == 1
    err = capsys.readouterr().err
    assert "--runs-split loro: one recording is split in time" in err and err.count("\n") == 1
