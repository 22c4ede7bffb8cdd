"""`thermal-comp calibrate` on several runs: one fit over the training runs (each simulated from
its own initial state), split by run, per-run and pooled figures; runs that do not match are refused."""
from __future__ import annotations

import json

import numpy as np
import pytest

from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.fit import CalibrationError
from thermal_twin.calibrate.runs import calibrate_runs, holdout_indices, own_reference
from thermal_twin.machine.schema import load_machine
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import write_recording_csv
from moved_mini_mill import SECTION, TRUE, TWIN, moved_runs

@pytest.fixture(scope="module")
def runs():
    """Three 12 h runs of the moved twin."""
    return moved_runs(3, 12.0, 10)


def test_runs_together_recover_the_moved_parameters_and_the_held_out_run_improves(runs):
    rc = calibrate_runs(TWIN, runs, ["a", "b", "c"], section=SECTION, max_nfev=30)
    est = {e.param.path: e.value for e in rc.result.estimates}
    for path, v in TRUE.items():
        assert est[path] == pytest.approx(v, rel=0.05), (path, est[path], v)
    assert [(x["name"], x["role"]) for x in rc.runs] == [("a", "train"), ("b", "train"), ("c", "holdout")]
    held = rc.runs[2]["channels"]
    for c in ("head_c", "spindle_c", "E_Z0T"):
        assert held[c]["rmse_after"] < 0.2 * held[c]["rmse_before"], (c, held[c])
    # one held-out run: the pooled held-out figure is that run's own
    pooled = rc.result.channel_table()
    assert pooled["E_Z0T"]["holdout_rmse_after"] == pytest.approx(held["E_Z0T"]["rmse_after"])
    # every run from its own initial state: the calibrated twin's run 'b' is the run simulated alone
    n_a = len(runs[0])
    y_b = rc.result.after["E_Z0T"][n_a:n_a + len(runs[1])]
    assert rmse(runs[1].columns["E_Z0T"], y_b) == pytest.approx(rc.runs[1]["channels"]["E_Z0T"]["rmse_after"])
    assert y_b[0] == pytest.approx(0.0, abs=1e-9)


def test_each_runs_displacements_are_taken_from_its_own_start(runs):
    # a run that starts where a longer recording had drifted to: offset by 3 um, first reading lost
    shifted = runs[1].slice(0, len(runs[1]))
    shifted.columns["E_Z0T"] = shifted.columns["E_Z0T"] + 3.0
    shifted.columns["E_Z0T"][0] = np.nan
    moved = own_reference(load_machine(TWIN), shifted)
    v = runs[1].columns["E_Z0T"]
    assert np.isnan(moved.columns["E_Z0T"][0])
    assert np.allclose(moved.columns["E_Z0T"][1:], v[1:] - v[1])
    assert np.array_equal(moved.columns["head_c"], runs[1].columns["head_c"])
    assert shifted.columns["E_Z0T"][2] == pytest.approx(v[2] + 3.0)      # the caller's run is left alone
    rc = calibrate_runs(TWIN, [runs[0], shifted, runs[2]], ["a", "b", "c"], section=SECTION, max_nfev=30)
    assert rc.runs[1]["channels"]["E_Z0T"]["rmse_after"] < 0.1


def test_holdout_by_count_or_name_and_its_errors():
    names = ["a", "b", "c", "d"]
    assert holdout_indices(names, None) == [3]
    assert holdout_indices(names, "2") == [2, 3]
    assert holdout_indices(names, "b,a") == [0, 1]
    with pytest.raises(CalibrationError, match=r"'x' is not a run"):
        holdout_indices(names, "x")
    with pytest.raises(CalibrationError, match=r"within \[1, 3\]"):
        holdout_indices(names, 4)
    with pytest.raises(CalibrationError, match="at least one"):
        holdout_indices(names, "a,b,c,d")


def test_a_run_whose_columns_differ_is_refused_naming_its_file(runs, tmp_path, capsys):
    paths = []
    for k, rec in enumerate(runs):
        cols = dict(rec.columns)
        if k == 2:
            cols.pop("table_c")
        paths.append(tmp_path / f"run{k}.csv")
        write_recording_csv(paths[-1], rec.time_s, cols)
    with pytest.raises(CalibrationError, match=r"run 'c' \(x.csv\): its columns differ .*missing table_c"):
        third = runs[2].slice(0, len(runs[2]))
        third.columns.pop("table_c")
        third.source = "x.csv"
        calibrate_runs(TWIN, [runs[0], runs[1], third], ["a", "b", "c"], section=SECTION)
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", *map(str, paths), "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "run 'run2'" in err and "run2.csv" in err and "missing table_c" in err
    assert main(["--twin", str(TWIN), "--recording", *map(str, paths[:2]), "--out", str(out), "--quiet",
                 "--holdout-fraction", "0.3"]) == 1
    assert "--holdout-runs" in capsys.readouterr().err
    assert main(["--twin", str(TWIN), "--recording", str(paths[0]), "--out", str(out), "--quiet",
                 "--holdout-runs", "1"]) == 1
    assert "one recording is split in time" in capsys.readouterr().err
    assert main(["--twin", str(TWIN), "--recording", str(tmp_path / "nothing*.csv"), "--out", str(out)]) == 1
    assert "matches no file" in capsys.readouterr().err


def test_cli_takes_a_folder_of_runs_and_reports_per_run_and_pooled(runs, tmp_path, capsys):
    folder = tmp_path / "runs"
    folder.mkdir()
    for k, rec in enumerate(runs):
        write_recording_csv(folder / f"day{k}.csv", rec.time_s, rec.columns)
    bounds = tmp_path / "bounds.yaml"
    bounds.write_text(json.dumps({"calibration": SECTION}))
    out = tmp_path / "cal"
    argv = ["--twin", str(TWIN), "--recording", str(folder), "--out", str(out), "--quiet",
            "--bounds", str(bounds), "--holdout-runs", "day0", "--max-nfev", "12"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "held-out runs pooled RMSE" in printed and "run day0 (holdout)" in printed
    rep = json.loads((out / "report.json").read_text())
    assert rep["split"]["by_run"] == {"train": ["day1", "day2"], "holdout": ["day0"]}
    assert [x["name"] for x in rep["runs"]] == ["day1", "day2", "day0"]
    day0 = rep["runs"][2]["channels"]["E_Z0T"]
    assert day0["rmse_after"] < day0["rmse_before"]
    assert rep["channels"]["E_Z0T"]["holdout_rmse_after"] == pytest.approx(day0["rmse_after"])
    md = (out / "report.md").read_text()
    assert "## RMSE per run" in md and "| day0 | holdout |" in md
    load_machine(out / "twin_calibrated.yaml")


def test_manifest_runs_in_date_order_and_each_runs_missing_speed_estimated(runs, tmp_path, capsys):
    for k, rec in enumerate(runs):
        cols = {c: v for c, v in rec.columns.items() if c != "spindle_rpm"}
        write_recording_csv(tmp_path / f"r{k}.csv", rec.time_s, cols)
    # listed out of date order: the last by date (r0) is the one held out
    (tmp_path / "m.yaml").write_text("runs:\n- {path: r0.csv, date: 2026-03-03}\n"
                                     "- {path: r1.csv, date: 2026-03-01}\n- {path: r2.csv, date: 2026-03-02}\n")
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", str(tmp_path / "m.yaml"), "--out", str(out), "--quiet",
                 "--max-nfev", "4"]) == 0
    capsys.readouterr()
    rep = json.loads((out / "report.json").read_text())
    assert rep["split"]["by_run"] == {"train": ["r1", "r2"], "holdout": ["r0"]}
    assert len(rep["input_estimates"]) == 3
    for k in range(3):
        assert (out / f"input_estimate_spindle_rpm_r{k}.png").is_file()
        assert any(n.startswith(f"run r{k}: ") and "spindle_rpm" in n for n in rep["notes"])
