"""``learn --sample-period-s``: a cell CSV without a time column is refused without the option
(the error names it) and read with it, row i at i x S seconds."""
from __future__ import annotations

import numpy as np

from thermal_eval.learn.cli import main as learn_main
from thermal_eval.learn.probes import cell_recording


def _untimed(path, rows: int = 20):
    """A temperature and a probe column every fourth row, no time column."""
    lines = ["ambient_c,E_X0C"] + [f"{20 + 0.1 * i},{0.5 * i if i % 4 == 0 else ''}" for i in range(rows)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_learn_reads_a_csv_without_time_column_only_with_a_sample_period(tmp_path, capsys):
    path = _untimed(tmp_path / "cell.csv")
    args = [str(path), "--twin", "nmv5000", "--no-prior", "--quiet"]
    assert learn_main(args + ["--out", str(tmp_path / "a")]) == 2
    assert "no time column: give the sample period, e.g. --sample-period-s" in capsys.readouterr().err
    rec, probes = cell_recording(path, sample_period_s=1800.0)
    np.testing.assert_allclose(rec.time_s, np.arange(20) * 1800.0)
    np.testing.assert_allclose(probes.time_s, np.arange(0, 20, 4) * 1800.0)
    # read through the command: its split refusal measures the recording in the period's hours
    assert learn_main(args + ["--out", str(tmp_path / "b"), "--sample-period-s", "1800"]) == 2
    assert "of the 9.5 h recording held out" in capsys.readouterr().err
    # several runs: every run is read with the period
    other = _untimed(tmp_path / "cell2.csv", rows=12)
    assert learn_main([str(path), str(other), "--twin", "nmv5000", "--no-prior", "--quiet",
                       "--out", str(tmp_path / "c")]) == 2
    assert "--sample-period-s" in capsys.readouterr().err
    assert learn_main([str(path), str(other), "--twin", "nmv5000", "--no-prior", "--quiet",
                       "--out", str(tmp_path / "d"), "--sample-period-s", "1800"]) == 2
    err = capsys.readouterr().err           # both read; refused further on, for too few probes
    assert "time" not in err and "field 'E_X0C' has 4 probes in its fit window" in err
