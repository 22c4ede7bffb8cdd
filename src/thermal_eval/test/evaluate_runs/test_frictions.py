"""A new user's recording: no time column, one held-out window, names with spaces, Excel files."""
from __future__ import annotations

import json

import numpy as np
import pytest

from thermal_comp_common.recording_csv import RecordingError, read_recording_text
from thermal_eval.evaluate.cli import main
from thermal_eval.evaluate.report import entity_part
from thermal_eval.evaluate.spec import make_split


def _rows(n: int = 400, sep: str = ",", dec: str = ".") -> str:
    rng = np.random.default_rng(1)
    a = 20 + np.cumsum(rng.normal(0, 0.02, n))
    lines = [sep.join(["T spindle_c", "hall_c", "delta L"])]
    for i in range(n):
        vals = [f"{a[i]:.4f}", f"{20 + 0.1 * np.sin(i / 50):.4f}", f"{2.0 * (a[i] - a[0]):.3f}"]
        lines.append(sep.join(v.replace(".", dec) for v in vals))
    return "\n".join(lines) + "\n"


def test_time_from_a_sample_period_when_there_is_no_time_column():
    rec = read_recording_text(_rows(5), "my.csv", sample_period_s=60.0)
    np.testing.assert_array_equal(rec.time_s, [0.0, 60.0, 120.0, 180.0, 240.0])
    assert list(rec.columns) == ["T spindle_c", "hall_c", "delta L"] and "row index x 60 s" in rec.warnings[-1]
    with pytest.raises(RecordingError, match="my.csv: line 1: .*--sample-period-s"):
        read_recording_text(_rows(5), "my.csv")
    with pytest.raises(RecordingError, match="sample period 0"):
        read_recording_text(_rows(5), "my.csv", sample_period_s=0)


def test_one_held_out_window_by_fractions_or_rows():
    s = make_split(1000, {"train": 0.6, "validation": 0.4, "test": 0.0})
    assert (s.n_train, s.validation, s.test.stop - s.test.start) == (600, slice(600, 1000), 0)
    assert s.as_dict()["test"] is None and [w for w, _ in s.windows()] == ["validation"]
    s = make_split(4683, {"train_end": 2810, "held_out_boundary": 4683})
    assert s.validation == slice(2810, 4683) and s.as_dict()["test"] is None
    s = make_split(1000, {"train": 0.6, "validation": 0.2, "test": 0.2})
    assert (s.validation, s.test) == (slice(600, 800), slice(800, 1000))


def test_an_excel_file_without_time_with_spaces_and_one_window(tmp_path, capfd):
    p = tmp_path / "spindle.csv"
    p.write_text(_rows(sep=";", dec=","), encoding="utf-8")
    out = tmp_path / "out"
    rc = main([str(p), "--out", str(out), "--sample-period-s", "60", "--displacements", "delta L",
               "--split", "0.6,0.4,0", "--models", "lagged_ridge", "--no-progress"])
    assert rc == 0, capfd.readouterr().err
    f = json.loads((out / "evaluation.json").read_text())
    cell = f["open_loop"]["lagged_ridge"]["channels"]["delta L"]
    assert cell["mae_test_um"] is None and cell["rmse_validation_um"] > 0 and cell["p99_validation_um"] > 0
    assert f["rows"]["test"] is None and f["ratio_baseline"] == "static_ls"
    printed = capfd.readouterr()
    assert "rerun" not in printed.err.lower() and "P99" in printed.out


def test_errors_name_the_users_file_not_a_temporary_copy(tmp_path, capsys):
    p = tmp_path / "excel.csv"
    p.write_text("time_s;a_c;z_um\n0;20,0;0,0\n60;twenty;0,1\n", encoding="utf-8")
    assert main([str(p), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(p) in err and "'twenty'" in err and "/tmp" not in err.replace(str(tmp_path), "")


def test_rerun_entity_parts_have_no_spaces():
    assert entity_part("delta L") == "delta_L" and entity_part("ch1_um") == "ch1_um"


def test_a_quantised_signal_is_detected_and_its_step_is_the_dead_band():
    from thermal_eval.evaluate.adaptive import dead_band_um, reading_noise_um, resolution_um
    rng = np.random.default_rng(3)
    smooth = np.cumsum(rng.normal(0, 0.03, 2000))
    y = np.round(smooth / 0.13) * 0.13                   # a gauge with 0.13 um steps
    assert reading_noise_um(y, 1500) == 0.0               # most changes are 0: the noise says nothing
    assert resolution_um(y, 1500) == pytest.approx(0.13, abs=1e-9)
    assert dead_band_um(y, 1500) == pytest.approx(0.13, abs=1e-9)
    assert resolution_um(smooth + rng.normal(0, 0.05, 2000), 1500) == 0.0   # a continuous signal is not


def test_the_table_says_when_a_channel_is_quantised(capsys):
    from thermal_eval.evaluate.report import quantised_notes
    f = {"adaptive": {"m": {"channels": {"delta L": {"quantised_step_um": 0.13, "dead_band_um": 0.13},
                                         "x_um": {"quantised_step_um": 0.0, "dead_band_um": 0.1}}}}}
    assert quantised_notes(f) == ["note: delta L is quantised in steps of 0.13 um (measured on the training rows): "
                                  "changes below the dead band of 0.13 um are not acted on"]
