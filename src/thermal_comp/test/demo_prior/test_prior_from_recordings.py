"""``thermal-comp prior --from-recordings``: runs from files, folders and globs, the history prior
written with its integrity fields, one-line refusals."""
import json
import math

import numpy as np
import pytest

from talc_model.prior.common import PriorError
from thermal_comp.prior.build import recording_paths
from thermal_comp.prior.cli import main
from thermal_comp_common.recording_csv import write_recording_csv


def _write_runs(folder, n=3):
    folder.mkdir()
    for seed in range(n):
        rng = np.random.default_rng(seed)
        t = np.arange(0.0, 12 * 3600.0, 300.0)
        amb = 20 + rng.uniform(0.5, 2) * np.sin(2 * np.pi * t / (rng.uniform(4, 20) * 3600) + rng.uniform(0, 6))
        a = math.exp(-300.0 / 10800.0)
        e = np.zeros_like(t)
        for k in range(1, t.size):
            e[k] = a * e[k - 1] + (1 - a) * 3.0 * (amb[k - 1] - amb[0])
        write_recording_csv(folder / f"day{seed + 1}.csv", t, {"hall_c": amb, "ch1_um": e})
    return folder


def test_files_folders_and_globs_in_order(tmp_path):
    runs = _write_runs(tmp_path / "runs")
    names = [p.name for p in recording_paths(str(runs))]
    assert names == ["day1.csv", "day2.csv", "day3.csv"]
    assert [p.name for p in recording_paths(f"{runs}/day3.csv,{runs}/day[12].csv")] == ["day3.csv", "day1.csv", "day2.csv"]
    with pytest.raises(PriorError, match="matches no file"):
        recording_paths(f"{runs}/nope*.csv")
    with pytest.raises(PriorError, match="no such file"):
        recording_paths(str(tmp_path / "missing.csv"))


def test_history_prior_written_with_its_identity(tmp_path, capsys):
    runs = _write_runs(tmp_path / "runs")
    out = tmp_path / "prior.json"
    assert main(["--from-recordings", str(runs), "--machine", "mill-3", "--out", str(out)]) == 0
    assert "history; held out" in capsys.readouterr().out
    prior = json.loads(out.read_text())
    assert prior["identity"]["prior_source"] == "history" and prior["identity"]["machine"] == "mill-3"
    assert prior["identity"]["input_names"] == ["hall"] and prior["held_out"][0].endswith("day3.csv")
    assert main(["--from-recordings", str(runs / "day1.csv"), "--out", str(tmp_path / "one.json")]) == 2
    assert "need at least 2" in capsys.readouterr().err


def test_runs_without_time_column_are_read_only_with_a_sample_period(tmp_path, capsys):
    runs = _write_runs(tmp_path / "runs")
    untimed = tmp_path / "untimed"
    untimed.mkdir()
    for p in sorted(runs.glob("*.csv")):
        (untimed / p.name).write_text("\n".join(line.split(",", 1)[1] for line in p.read_text().splitlines()) + "\n")
    out = tmp_path / "prior.json"
    assert main(["--from-recordings", str(untimed), "--out", str(out)]) == 2
    assert "no time column: give the sample period, e.g. --sample-period-s" in capsys.readouterr().err
    assert main(["--from-recordings", str(untimed), "--out", str(out), "--sample-period-s", "300"]) == 0
    assert main(["--from-recordings", str(runs), "--out", str(tmp_path / "timed.json")]) == 0
    # row i at i x 300 s: the same prior as from the runs with their time column
    got, want = json.loads(out.read_text()), json.loads((tmp_path / "timed.json").read_text())
    assert got["validation_rms"] == want["validation_rms"]
    with pytest.raises(SystemExit):
        main(["--out", str(out), "--sample-period-s", "300"])
    assert "only with --from-recordings" in capsys.readouterr().err
