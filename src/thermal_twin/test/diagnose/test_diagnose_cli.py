"""`thermal-comp diagnose` end to end on a CSV, and its answers to bad input."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from thermal_twin.diagnose.cli import main
from thermal_twin.machine.schema import load_machine
from thermal_eval.diagnose.concealed import HiddenEffect, concealed_recording
from thermal_comp_common.recording_csv import write_recording_csv

HERE = pathlib.Path(__file__).parent
TWIN = HERE / "mini_mill.yaml"


@pytest.fixture(scope="module")
def recording_csv(tmp_path_factory) -> pathlib.Path:
    spec = load_machine(TWIN).to_dict()
    rec, _ = concealed_recording(spec, [HiddenEffect("door_event", "head", "door_open", (30.0,))],
                                 hours=36.0, step_s=300.0, seed=11)
    path = tmp_path_factory.mktemp("rec") / "rec.csv"
    write_recording_csv(path, rec.time_s, rec.columns)
    return path


def test_cli_writes_report_plots_rerun_and_augmented_twin(recording_csv, tmp_path, capsys):
    out = tmp_path / "diag"
    assert main(["--twin", str(TWIN), "--recording", str(recording_csv), "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "selected: door_event on head driven by door_open" in printed
    rep = json.loads((out / "report.json").read_text())
    for ch, d in rep["channels"].items():
        for k in ("rmse_before", "rmse_after", "holdout_rmse_before", "holdout_rmse_after"):
            assert isinstance(d[k], float), (ch, k)
    assert rep["channels"]["head_c"]["holdout_rmse_after"] < 0.5 * rep["channels"]["head_c"]["holdout_rmse_before"]
    for w in rep["windows"]:
        assert {"start_s", "end_s", "channels", "regime"} <= set(w)
    assert rep["windows"], "a 30 W/K door effect must be located"
    h0 = rep["hypotheses"][0]
    assert {"effect", "target", "driver", "params", "score", "holdout_improvement_pct"} <= set(h0)
    assert all(set(p) == {"value", "unit"} for p in h0["params"].values())
    assert [s["effect"] for s in rep["selected"]] == ["door_event"]
    aug = load_machine(out / rep["augmented_twin"])
    link = next(l for l in aug.links.values() if {l.a, l.b} == {"head", "ambient"})
    assert link.varies_with and link.varies_with[0][0] == "door_open"
    assert aug.sensors["head"].noise_std == 0.02, "the augmented twin keeps the sensor model"
    md = (out / "report.md").read_text()
    for png in ("residuals.png", "cross_correlation.png"):
        assert f"({png})" in md and (out / png).stat().st_size > 10_000
    assert (out / "diagnosis.rrd").stat().st_size > 10_000


def test_cli_bad_inputs_give_one_clear_line(recording_csv, tmp_path, capsys):
    out = str(tmp_path / "x")
    assert main(["--twin", str(TWIN), "--recording", str(recording_csv), "--out", out,
                 "--effects", "heat_source,gremlins"]) == 2
    assert "'gremlins'" in capsys.readouterr().err
    assert main(["--twin", str(TWIN), "--recording", str(tmp_path / "rec.txt"), "--out", out]) == 2
    assert "neither a CSV nor a bag" in capsys.readouterr().err
    assert main(["--twin", str(TWIN), "--recording", str(tmp_path / "missing.mcap"), "--out", out]) == 1
    assert "missing.mcap" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    lines = recording_csv.read_text().splitlines()
    lines[5] = lines[5].replace(",", ",abc,", 1).replace(",abc,", ",abc", 1)
    bad.write_text("\n".join(lines) + "\n")
    assert main(["--twin", str(TWIN), "--recording", str(bad), "--out", out]) == 1
    err = capsys.readouterr().err
    assert "line 6" in err and "'abc" in err
    other = tmp_path / "other.csv"
    write_recording_csv(other, np.arange(50) * 60.0, {"spindle_rpm": np.zeros(50), "x9_c": np.ones(50)})
    assert main(["--twin", str(TWIN), "--recording", str(other), "--out", out]) == 1
    assert "no channel shared with twin 'mini_mill'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists(), "nothing written on bad input"


def test_cli_reads_a_bag_like_the_csv(recording_csv, tmp_path, capsys):
    from thermal_comp_common.bags.csv_to_bag import csv_to_bag
    bag = tmp_path / "bag"
    csv_to_bag(recording_csv, bag)
    out = tmp_path / "diag"
    assert main(["--twin", str(TWIN), "--recording", str(bag), "--out", str(out), "--quiet", "--no-rerun"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert [(s["effect"], s["target"], s["driver"]) for s in rep["selected"]] == [("door_event", "head", "door_open")]
    assert abs(rep["selected"][0]["params"]["dG_open"]["value"] - 30.0) < 8.0
    assert any("coolant_temperature_degc" in n for n in rep["notes"]), "an unusable bag field is reported"
    assert not (out / "diagnosis.rrd").exists()


def test_failed_readings_and_a_truncated_last_line_lose_nothing_else(recording_csv, tmp_path):
    """NaN readings (a failed sensor now and then) and a recorder killed mid-line: the
    diagnosis uses every good value and reports the truncation."""
    lines = recording_csv.read_text().splitlines()
    header = lines[0].split(",")
    j = header.index("head_c")
    rng = np.random.default_rng(0)
    for i in rng.choice(np.arange(1, len(lines)), size=len(lines) // 10, replace=False):
        cells = lines[i].split(",")
        cells[j] = "nan"
        lines[i] = ",".join(cells)
    damaged = tmp_path / "damaged.csv"
    damaged.write_text("\n".join(lines) + "\n" + lines[-1][:9] + "\n")
    out = tmp_path / "diag"
    assert main(["--twin", str(TWIN), "--recording", str(damaged), "--out", str(out), "--quiet", "--no-rerun"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert [(s["effect"], s["target"]) for s in rep["selected"]] == [("door_event", "head")]
    assert any("truncated" in n for n in rep["notes"])
    assert rep["channels"]["head_c"]["holdout_rmse_after"] < 0.5 * rep["channels"]["head_c"]["holdout_rmse_before"]


def test_an_existing_output_folder_is_refused_and_an_empty_column_named(recording_csv, tmp_path, capsys):
    """A second diagnosis over the first one's folder is refused (nothing overwritten) unless
    --force; a column without any value is named in the report's notes, not dropped silently."""
    import numpy as np

    from thermal_comp_common.recording_csv import read_recording_csv
    from thermal_twin.diagnose.cli import main
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.md").write_text("the first run's report")
    assert main(["--twin", "spindle-stand", "--recording", str(tmp_path / "missing.csv"),
                 "--out", str(out), "--quiet"]) == 2
    assert "exists and is not empty (use --force)" in capsys.readouterr().err
    assert (out / "report.md").read_text() == "the first run's report"
    from thermal_twin.calibrate.column_mapping import empty_columns
    rec = read_recording_csv(recording_csv)
    rec.columns["dead_c"] = np.full(len(rec), np.nan)
    assert empty_columns(rec) == ["dead_c"]


def test_a_csv_without_time_column_is_read_only_with_a_sample_period(recording_csv, tmp_path, capsys):
    from thermal_comp_common.bags.csv_to_bag import csv_to_bag               # this test only
    untimed = tmp_path / "untimed.csv"
    untimed.write_text("\n".join(line.split(",", 1)[1] for line in recording_csv.read_text().splitlines()) + "\n")
    args = ["--twin", str(TWIN), "--recording", str(untimed), "--quiet", "--no-rerun", "--max-effects", "0",
            "--no-unnamed", "--no-clock-offset"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 1
    assert "no time column: give the sample period, e.g. --sample-period-s" in capsys.readouterr().err
    out = tmp_path / "b"
    assert main(args + ["--out", str(out), "--sample-period-s", "300"]) == 0
    rep = json.loads((out / "report.json").read_text())
    rows = len(recording_csv.read_text().splitlines()) - 1
    assert rep["split"]["end_s"] == pytest.approx((rows - 1) * 300.0)       # row i at i x 300 s
    bag = tmp_path / "bag"
    csv_to_bag(recording_csv, bag)
    assert main(["--twin", str(TWIN), "--recording", str(bag), "--out", str(tmp_path / "c"),
                 "--sample-period-s", "300"]) == 1
    assert "a bag has its own time stamps" in capsys.readouterr().err
