"""An input the recording lacks (the spindle speed) is estimated from the temperatures:
the heat profile tracks the heat of the deleted speed, and `calibrate` reports it."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.input_estimation import estimate_input, missing_inputs, source_power
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate
from thermal_eval.diagnose.concealed import operating_programme
from thermal_comp_common.recording_csv import write_recording_csv

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"


@pytest.fixture(scope="module")
def speedless():
    m = load_machine(TWIN)
    rec = simulate(m, operating_programme(m.to_dict(), 36.0, 300.0, seed=5), seed=1).to_recording()
    speed = rec.columns.pop("spindle_rpm")
    return m, rec, speed


def test_heat_profile_tracks_the_deleted_speed(speedless):
    m, rec, speed = speedless
    assert missing_inputs(m, rec) == ["spindle_rpm"]
    chans = [c for c in rec.columns if c.endswith("_c") or c.startswith("E_")]
    est = estimate_input(m, rec, "spindle_rpm", chans, block_s=1800.0)
    true = source_power(m, "spindle_rpm", speed)
    e = est.block_edges_s
    block_true = np.array([true[(rec.time_s >= a) & (rec.time_s < b)].mean() for a, b in zip(e[:-1], e[1:])])
    assert np.corrcoef(block_true, est.power_w)[0, 1] > 0.97
    assert np.mean(est.power_w) == pytest.approx(np.mean(block_true), rel=0.1)
    # the 95 % band covers most blocks' true heat
    inside = (block_true >= est.power_ci95_w[:, 0] - 1e-9) & (block_true <= est.power_ci95_w[:, 1] + 1e-9)
    assert inside.mean() > 0.7
    # equivalent speed where the spindle ran steadily through a block
    run = block_true > 0.5 * block_true.max()
    u_true = np.array([speed[(rec.time_s >= a) & (rec.time_s < b)].mean() for a, b in zip(e[:-1], e[1:])])
    assert np.median(np.abs(est.equivalent_input[run] - u_true[run]) / u_true[run]) < 0.15


def test_calibrate_estimates_the_missing_input_and_says_so(speedless, tmp_path, capsys):
    _, rec, _ = speedless
    csv = tmp_path / "rec.csv"
    write_recording_csv(csv, rec.time_s, rec.columns)
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", str(csv), "--out", str(out), "--quiet",
                 "--max-nfev", "3"]) == 0
    rep = json.loads((out / "report.json").read_text())
    (est,) = rep["input_estimates"]
    assert est["input"] == "spindle_rpm" and est["mean_power_w"] > 0
    assert any("input 'spindle_rpm' is not in the recording: estimated" in n for n in rep["notes"])
    assert (out / "input_estimate_spindle_rpm.png").is_file()
    assert "estimated from the temperatures" in capsys.readouterr().out
