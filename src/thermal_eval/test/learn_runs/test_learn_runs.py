"""thermal-comp learn on several runs of one unit: the twin is calibrated on the training runs
jointly (each from its own start), adopted on the validation runs, scored per held-out run and
pooled; a held-out run never changes the fit; one recording is learned as before; every bad run
is refused in one line naming the run and the field."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from learn_runs_fixture import COMPS, TWIN, write_runs
from thermal_comp_common.recording_csv import read_recording_csv, write_recording_csv
from thermal_comp_common.run_splits import run_splits
from thermal_eval.learn.cli import main as learn_main
from thermal_eval.learn.runs import cell_runs, learn_runs

NFEV = ["--max-nfev", "4", "--no-prior", "--quiet"]


@pytest.fixture(scope="module")
def days(tmp_path_factory):
    return write_runs(tmp_path_factory.mktemp("runs"), 4)


def _manifest(tmp_path, paths, units=None) -> str:
    rows = [{"path": str(p), "unit": (units or ["U1"] * len(paths))[k], "programme": "mixed",
             "date": f"2026-03-0{k + 1}", "hall_setpoint_c": 20} for k, p in enumerate(paths)]
    m = tmp_path / "runs.yaml"
    m.write_text(yaml.safe_dump({"runs": rows}))
    return str(m)


def test_several_runs_give_a_joint_twin_scored_per_run_and_pooled(days, tmp_path):
    out = tmp_path / "out"
    assert learn_main([_manifest(tmp_path, days), "--twin", str(TWIN), "--out", str(out),
                       "--runs-split", "test=day4;validation=day3", *NFEV]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert [(r["name"], r["role"]) for r in rep["runs"]] == [("day1", "train"), ("day2", "train"),
                                                             ("day3", "validation"), ("day4", "test")]
    assert rep["runs"][0]["unit"] == "U1" and rep["runs"][0]["date"] == "2026-03-01"
    assert rep["validation_rule"].startswith("every probe of the validation runs")
    assert sorted(rep["scores"]["per_run"]) == ["day3", "day4"] and set(rep["scores"]["pooled"]) == {"test", "validation"}
    test = rep["scores"]["pooled"]["test"]
    assert all(test["twin (unit), open loop"][c]["n"] == 12 for c in COMPS)
    # the moved link and loss law are learned: the unseen run is predicted better open loop
    assert sum(test["twin (unit), open loop"][c]["rmse"] for c in COMPS) < \
        0.7 * sum(test["twin (type), open loop"][c]["rmse"] for c in COMPS), test
    assert rep["adoption"]["adopt"] and rep["adoption"]["validation_probes"] == 12
    md = (out / "report.md").read_text()
    for name, row in test.items():                    # every pooled RMSE in the md is the JSON's
        assert f"| {name} | " + " | ".join(f"{row[c]['rmse']:.3g}" for c in COMPS) + " |" in md
    assert (out / "unit_twin.yaml").is_file() and "day1, day2" in (out / "unit_twin.yaml").read_text()


def test_a_folder_of_three_runs_takes_the_default_split_one_run_each(days, tmp_path):
    folder = tmp_path / "three"
    folder.mkdir()
    for p in days[:3]:
        (folder / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "out3"
    assert learn_main([str(folder), "--twin", str(TWIN), "--out", str(out), *NFEV]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["split"] == "0.6,0.2,0.2"
    assert [(r["name"], r["role"]) for r in rep["runs"]] == [("day1", "train"), ("day2", "validation"),
                                                             ("day3", "test")]
    assert rep["adoption"]["validation_probes"] == 12 and sorted(rep["scores"]["pooled"]) == ["test", "validation"]


def test_a_corrupted_held_out_run_does_not_change_the_fitted_twin(days, tmp_path):
    bad = write_runs(tmp_path / "bad", 4, corrupt={3: 1000.0})
    fold = lambda runs: run_splits([r.entry for r in runs], "test=day4")[0]       # noqa: E731
    clean, dirty = cell_runs([str(p) for p in days]), cell_runs([str(p) for p in bad])
    a = learn_runs(str(TWIN), clean, fold(clean), tmp_path / "a", max_nfev=4, build_priors=False)
    b = learn_runs(str(TWIN), dirty, fold(dirty), tmp_path / "b", max_nfev=4, build_priors=False)
    assert [p["value"] for p in a["parameters"]] == [p["value"] for p in b["parameters"]]
    assert (tmp_path / "a" / "unit_twin.yaml").read_text() == (tmp_path / "b" / "unit_twin.yaml").read_text()
    assert a["adoption"] == b["adoption"]
    assert "the last quarter of every training run" in a["validation_rule"]
    held = lambda r: r["scores"]["per_run"]["day4"]["twin (unit), open loop"]["E_Z0T"]["rmse"]   # noqa: E731
    assert held(b) > 900.0 > 10.0 > held(a)            # the corruption is scored, never fitted


def test_one_recording_is_learned_as_before(days, tmp_path):
    reports = []
    for k, src in enumerate([str(days[0]), _manifest(tmp_path, days[:1])]):
        out = tmp_path / f"one{k}"
        assert learn_main([src, "--twin", str(TWIN), "--out", str(out), "--train-h", "4", "--validate-h", "1",
                           *NFEV]) == 0
        reports.append(json.loads((out / "report.json").read_text()))
    a, b = reports
    assert a["held_out_scores"] == b["held_out_scores"] and a["parameters"] == b["parameters"]
    assert "runs" not in a and a["train_h"] == 4


def test_leave_one_run_out_learns_once_per_fold_and_pools_the_held_out_runs(days, tmp_path):
    out = tmp_path / "loro"
    assert learn_main([*map(str, days[:3]), "--twin", str(TWIN), "--out", str(out), "--runs-split", "loro", *NFEV]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert [f["test"] for f in rep["folds"]] == [["day1"], ["day2"], ["day3"]]
    assert all((out / "folds" / f"0{k}" / "unit_twin.yaml").is_file() for k in (1, 2, 3))
    assert {r["role"] for r in rep["runs"]} == {"train"}          # the twin written: every run
    pooled = rep["pooled_over_folds"]["twin (unit), open loop"]
    assert all(pooled[c]["n"] == 3 * 12 for c in COMPS)
    one = [f["scores"][f["test"][0]]["twin (unit), open loop"]["E_Z0T"] for f in rep["folds"]]
    assert pooled["E_Z0T"]["rmse"] == pytest.approx(np.sqrt(np.mean([o["rmse"] ** 2 for o in one])))
    md = (out / "report.md").read_text()
    assert "| twin (unit), open loop | " + " | ".join(f"{pooled[c]['rmse']:.3g}" for c in COMPS) + " |" in md


@pytest.mark.parametrize("case, match", [
    ("missing", r"source '.*nope.csv': no such file or folder"),
    ("glob", r"source '.*zz\*.csv': the pattern matches no file"),
    ("twice", r"run 'day1': file .*day1.csv is listed twice"),
    ("no_probes", r"run 'empty': .*no probing result"),
    ("columns", r"run 'cols' \(.*\): field 'columns' differs from run 'day1': extra_degc"),
    ("units", r"run 'day2': field 'unit' = 'U2' differs from run 'day1' \('U1'\)"),
    ("few", r"run 'short' \(.*\): field 'E_Z0T' has 3 probes in its fit window, need at least 8"),
    ("train_h", r"--train-h 4: splits one recording in time"),
    ("one_split", r"--runs-split loro: .*day1.csv is one run"),
])
def test_bad_runs_are_refused_in_one_line(days, tmp_path, capsys, case, match):
    d = [str(p) for p in days[:3]]
    extra = []
    if case == "missing":
        srcs = d[:2] + [str(tmp_path / "nope.csv")]
    elif case == "glob":
        srcs = d[:2] + [str(tmp_path / "zz*.csv")]
    elif case == "twice":
        srcs = d[:2] + [d[0]]
    elif case in ("no_probes", "columns", "few"):
        rec = read_recording_csv(d[2])
        cols, t = dict(rec.columns), rec.time_s
        name = {"no_probes": "empty", "columns": "cols", "few": "short"}[case]
        if case == "no_probes":
            cols.update({c: np.full(len(rec), np.nan) for c in COMPS})
        elif case == "columns":
            cols["extra_degc"] = np.full(len(rec), 20.0)
        else:
            k = int(len(rec) * 0.3)
            cols, t = {c: v[:k] for c, v in cols.items()}, t[:k]
        write_recording_csv(tmp_path / f"{name}.csv", t, cols)
        srcs = [str(tmp_path / f"{name}.csv")] + d[:2] if case == "few" else d[:2] + [str(tmp_path / f"{name}.csv")]
        extra = ["--runs-split", "test=day2"] if case == "few" else []
    elif case == "units":
        srcs = [_manifest(tmp_path, days[:3], ["U1", "U2", "U1"])]
    elif case == "train_h":
        srcs, extra = d, ["--train-h", "4"]
    else:
        srcs, extra = d[:1], ["--runs-split", "loro"]
    assert learn_main([*srcs, "--twin", str(TWIN), "--out", str(tmp_path / "o"), *extra, *NFEV]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("thermal-comp learn: "), err
    assert re.search(match, err), err
    assert not (tmp_path / "o").exists()          # a refused learning leaves no folder behind


def test_a_refusal_keeps_a_folder_the_user_made(days, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    assert learn_main([str(days[0]), str(days[0]), "--twin", str(TWIN), "--out", str(out), *NFEV]) == 2
    assert out.is_dir()
