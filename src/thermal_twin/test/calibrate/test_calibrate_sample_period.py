"""``calibrate --sample-period-s``: a CSV without a time column is refused without the option
(the error names it) and read with it, row i at i x S seconds."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from thermal_comp_common.recording_csv import write_recording_csv
from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.column_mapping import read_real_recording
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate
from thermal_eval.diagnose.concealed import operating_programme

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"
PERIOD = 300.0


@pytest.fixture(scope="module")
def untimed(tmp_path_factory):
    m = load_machine(TWIN)
    rec = simulate(m, operating_programme(m.to_dict(), 12.0, PERIOD, seed=2), seed=0).to_recording()
    d = tmp_path_factory.mktemp("untimed")
    timed = d / "timed.csv"
    write_recording_csv(timed, rec.time_s, rec.columns)
    path = d / "untimed.csv"
    path.write_text("\n".join(line.split(",", 1)[1] for line in timed.read_text().splitlines()) + "\n")
    return timed, path


def test_calibrate_reads_a_csv_without_time_column_only_with_a_sample_period(untimed, tmp_path, capsys):
    timed, untimed = untimed
    assert main(["--twin", str(TWIN), "--recording", str(untimed), "--out", str(tmp_path / "a"), "--quiet"]) != 0
    assert "no time column: give the sample period, e.g. --sample-period-s" in capsys.readouterr().err
    rec = read_real_recording(untimed, sample_period_s=PERIOD)
    np.testing.assert_allclose(rec.time_s, np.arange(len(rec)) * PERIOD)
    out = tmp_path / "b"
    assert main(["--twin", str(TWIN), "--recording", str(untimed), "--sample-period-s", str(PERIOD),
                 "--out", str(out), "--quiet", "--max-nfev", "2"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["split"]["end_s"] == pytest.approx((len(rec) - 1) * PERIOD)
    # a file with its own time column and a period: refused, never one silently preferred
    assert main(["--twin", str(TWIN), "--recording", str(timed), "--sample-period-s", "60",
                 "--out", str(tmp_path / "c"), "--quiet"]) != 0
    assert "has a 'time_s' column and a sample period was given" in capsys.readouterr().err
