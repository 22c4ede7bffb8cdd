"""thermal-comp replay refuses what it cannot score honestly, in one line and before the long work:
a bag that ends early (unless --allow-truncated), too few rows, infinite or absurd values, an
output path that cannot be written; a NaN figure is never printed as a result."""
from __future__ import annotations

import json
import math

import pytest

from thermal_comp_common.bags.csv_to_bag import csv_to_bag
from thermal_comp_common.bags.truncation import ALLOW_TRUNCATED_ENV
from thermal_comp_common.recording_csv import read_recording_csv, write_recording_csv
from thermal_eval.replay.cli import main as replay_main
from thermal_eval.replay.summary import format_table

TALC = ["--model", "talc", "--set", "preset=table_6_3_A", "--set", "input_names=[ambient, ws_mwf, c_coolant_delta]",
        "--set", "cp_length_h=2", "--no-progress"]


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("thermal-comp replay: "), err
    return lines[0]


@pytest.fixture(scope="module")
def cut_bag(short_csv, tmp_path_factory):
    """The short recording as a bag cut at half its MCAP file (a recorder killed between flushes)."""
    bag = tmp_path_factory.mktemp("cut") / "bag"
    csv_to_bag(short_csv, bag, chunk_bytes=4096)
    mcap = bag / "bag_0.mcap"
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    return bag


def test_a_cut_bag_is_refused_naming_where_it_ends_unless_allowed(cut_bag, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert replay_main([str(cut_bag), *TALC, "--json", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "the bag ends early, it ends at t = " in line and "h after its first instant" in line, line
    assert "--allow-truncated" in line and not out.exists()
    assert replay_main([str(cut_bag), *TALC, "--allow-truncated", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert 1.0 < data["duration_h"] < 11.0
    assert "warning: " in capsys.readouterr().err     # what was used is said
    assert ALLOW_TRUNCATED_ENV not in __import__("os").environ     # the permission ended with the command


def test_too_few_rows_and_broken_values_are_refused_in_one_line(short_csv, tmp_path, capsys):
    rec = read_recording_csv(short_csv)
    one = tmp_path / "one_row.csv"
    write_recording_csv(one, rec.time_s[:1], {k: v[:1] for k, v in rec.columns.items()})
    assert replay_main([str(one), *TALC, "--json", str(tmp_path / "one.json")]) == 2
    assert "1 rows, need at least 30" in _one_line(capsys.readouterr().err)
    # written as text: the CSV writer itself never writes an infinite value
    header, *lines = short_csv.read_text().splitlines()
    names = header.split(",")
    for text, col in (("inf", "E_Y0C"), ("1e9", "ambient_c")):
        rows = [line.split(",") for line in lines]
        rows[40][names.index(col)] = text
        path = tmp_path / f"{col}.csv"
        path.write_text("\n".join([header] + [",".join(r) for r in rows]) + "\n")
        assert replay_main([str(path), *TALC, "--json", str(tmp_path / f"{col}.json")]) == 2
        line = _one_line(capsys.readouterr().err)
        assert f"column '{col}': row 41" in line and "is no measurement" in line, line
    cycle = ["nan", "inf", "1e9", "-inf"]
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([header] + [",".join([line.split(",")[0]] + [cycle[k % 4]] * (len(names) - 1))
                                          for k, line in enumerate(lines)]) + "\n")
    assert replay_main([str(bad), *TALC, "--json", str(tmp_path / "bad.json")]) == 2
    assert "is no measurement" in _one_line(capsys.readouterr().err)
    assert not list(tmp_path.glob("*.json"))


def test_an_output_path_that_cannot_be_written_is_refused_before_the_replay(short_csv, tmp_path, capsys):
    assert replay_main([str(short_csv), *TALC, "--json", "/proc/x.json"]) == 2
    assert "--json '/proc/x.json': cannot write there" in _one_line(capsys.readouterr().err)
    assert replay_main([str(short_csv), *TALC, "--json", str(tmp_path), "--png", str(tmp_path / "p.png")]) == 2
    assert "is a folder" in _one_line(capsys.readouterr().err)
    assert replay_main([str(short_csv), *TALC, "--json", str(tmp_path / "r.json"), "--png", "/proc/p.png"]) == 2
    assert "--png '/proc/p.png'" in _one_line(capsys.readouterr().err)
    assert list(tmp_path.iterdir()) == []      # nothing left by the trial writes


def test_a_nan_headline_is_printed_as_not_available():
    row = {"unit": "um", "p99": math.nan, "rms": math.nan, "p99_uncompensated": math.nan,
           "rms_uncompensated": math.nan}
    summary = {"components": {"E_X0C": row}, "p99_lin_um": math.nan, "p99_ang_um_per_m": math.nan,
               "q_prod_pct": 100.0, "calibration_h": math.nan, "probing_cycles": 0, "no_good_phases": 0,
               "parameter_updates": 0, "compensation_steps": 0, "scored_steps": 0, "scored_from_h": None}
    text = format_table(summary)
    assert "nan" not in text.lower().replace("n/a", "")
    assert "P99_lin n/a (nothing scored) um" in text


def test_evaluate_and_diagnose_refuse_a_cut_bag_unless_allowed(cut_bag, tmp_path, capsys):
    from thermal_eval.evaluate.cli import main as evaluate_main, parser as evaluate_parser
    from thermal_twin.diagnose.cli import build_parser as diagnose_parser, main as diagnose_main
    assert evaluate_main([str(cut_bag), "--out", str(tmp_path / "ev"), "--no-progress", "--no-rerun"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("thermal-comp evaluate: ") and "the bag ends early, it ends at t = " in err, err
    assert diagnose_main(["--twin", "nmv5000", "--recording", str(cut_bag), "--out", str(tmp_path / "dg"),
                          "--quiet", "--no-rerun"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("thermal-comp diagnose: ") and "the bag ends early, it ends at t = " in err, err
    assert evaluate_parser().parse_args([str(cut_bag), "--out", "x", "--allow-truncated"]).allow_truncated
    assert diagnose_parser().parse_args(["--twin", "t", "--recording", "r", "--out", "o",
                                         "--allow-truncated"]).allow_truncated


def test_sweep_refuses_a_cut_bag_unless_allowed(cut_bag, tmp_path, capsys):
    from thermal_eval.sweep.cli import main as sweep_main      # the sweep's CLI only in this test
    common = ["--limit", "1", "--jobs", "1", "--no-progress", "--set", "cp_length_h=2"]
    assert sweep_main([str(cut_bag), "--out", str(tmp_path / "refused"), *common]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("thermal-comp sweep: ") and "the bag ends early, it ends at t = " in err, err
    assert "\n" not in err and not (tmp_path / "refused" / "results.jsonl").exists()
    assert sweep_main([str(cut_bag), "--out", str(tmp_path / "allowed"), *common, "--allow-truncated"]) == 0
    assert "warning: " in capsys.readouterr().err
    assert (tmp_path / "allowed" / "results.jsonl").read_text().count("\n") == 1


def test_a_csv_without_time_column_is_read_only_with_a_sample_period(short_csv, tmp_path, capsys):
    rec = read_recording_csv(short_csv)
    period = float(rec.time_s[1] - rec.time_s[0])
    untimed = tmp_path / "untimed.csv"
    untimed.write_text("\n".join(line.split(",", 1)[1] for line in short_csv.read_text().splitlines()) + "\n")
    out = tmp_path / "r.json"
    assert replay_main([str(untimed), *TALC, "--json", str(out)]) == 2
    assert "no time column: give the sample period, e.g. --sample-period-s" in _one_line(capsys.readouterr().err)
    assert replay_main([str(untimed), *TALC, "--sample-period-s", f"{period:g}", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["duration_h"] == pytest.approx((len(rec) - 1) * period / 3600.0)
    # several runs: every run read with the period
    second = tmp_path / "second.csv"
    second.write_text(untimed.read_text())
    assert replay_main([str(untimed), str(second), *TALC, "--sample-period-s", f"{period:g}",
                        "--json", str(tmp_path / "two.json")]) == 0
    runs = json.loads((tmp_path / "two.json").read_text())["runs"]
    assert [r["duration_h"] for r in runs] == [pytest.approx((len(rec) - 1) * period / 3600.0)] * 2


def test_sweep_reads_a_csv_without_time_column_only_with_a_sample_period(short_csv, tmp_path, capsys):
    from thermal_eval.sweep.cli import main as sweep_main      # the sweep's CLI only in this test
    untimed = tmp_path / "untimed.csv"
    untimed.write_text("\n".join(line.split(",", 1)[1] for line in short_csv.read_text().splitlines()) + "\n")
    common = ["--limit", "1", "--jobs", "1", "--no-progress", "--set", "cp_length_h=2"]
    assert sweep_main([str(untimed), "--out", str(tmp_path / "refused"), *common]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("thermal-comp sweep: ") and "--sample-period-s" in err, err
    rec = read_recording_csv(short_csv)
    period = f"{float(rec.time_s[1] - rec.time_s[0]):g}"
    assert sweep_main([str(untimed), "--out", str(tmp_path / "ok"), *common, "--sample-period-s", period]) == 0
    assert (tmp_path / "ok" / "results.jsonl").read_text().count("\n") == 1
