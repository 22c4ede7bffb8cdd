"""`thermal-comp calibrate` recovers parameters a twin recording was made with, says what it
cannot identify, and handles the output directory and empty columns as documented."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.fit import calibrate
from thermal_twin.calibrate.bounds import CalibrationSpecError, free_parameters
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate
from thermal_eval.diagnose.concealed import operating_programme
from thermal_comp_common.recording_csv import write_recording_csv

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"
TRUE = {("links", "spindle_head", "conductance"): 8.0 * 1.6,
        ("links", "table_air", "conductance"): 6.0 * 0.6,
        ("sources", "spindle_losses", "coefficient"): 0.00015396 * 1.4,
        ("errors", "E_Z0T", "terms", "spindle"): 2.6,
        ("sensors", "head", "bias"): 0.3}
# the truth lies beyond the default tolerances (+-30 %): this test states wider ones
SECTION = {"kinds": {"capacity": "fixed", "conductance": {"factor": 2.0}, "source": {"factor": 2.0},
                     "gain": {"tolerance": 1.0, "absolute": 1.0}, "bias": {"absolute": 1.0}}}


def _set(spec, path, v):
    d = spec
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = v


@pytest.fixture(scope="module")
def truth_recording():
    spec = load_machine(TWIN).to_dict()
    true = load_machine(TWIN).to_dict()
    for path, v in TRUE.items():
        _set(true, path, v)
    tl = operating_programme(spec, hours=48.0, step_s=300.0, seed=3)
    return simulate(true, tl, seed=0).to_recording()


def test_recovers_the_parameters_a_recording_was_made_with(truth_recording):
    r = calibrate(TWIN, truth_recording, section=SECTION, max_nfev=40)
    est = {e.param.path: e for e in r.estimates}
    for path, v in TRUE.items():
        e = est[path]
        assert e.value == pytest.approx(v, rel=0.1, abs=0.03), (path, e.value, v)
        assert e.ci95[0] <= e.value <= e.ci95[1]
    table = r.channel_table()
    assert table["head_c"]["holdout_rmse_after"] < 0.3 * table["head_c"]["holdout_rmse_before"]
    assert table["E_Z0T"]["holdout_rmse_after"] < 0.3 * table["E_Z0T"]["holdout_rmse_before"]
    assert r.cost_after < 0.05 * r.cost_before
    assert r.simulated_h > 0 and r.n_evals > 0


def test_parameter_the_recording_does_not_see_is_flagged(truth_recording):
    # the ambient sensor reads the boundary itself: its placement says nothing about the
    # spindle's capacity when the spindle never runs -> a recording at standstill
    rec = truth_recording
    still = rec.slice(0, len(rec))
    still.columns["spindle_rpm"] = np.zeros(len(rec))
    r = calibrate(TWIN, still, section={"kinds": {k: "fixed" for k in
                                                   ("conductance", "gain", "bias", "capacity", "boundary")},
                                        "parameters": {"sources.spindle_losses.coefficient": {"factor": 3}}},
                  max_nfev=5)
    (e,) = r.estimates
    assert any(f.startswith("not identified") for f in e.flags)


def test_bounds_errors_name_the_key_and_closest_parameter():
    spec = load_machine(TWIN).to_dict()
    with pytest.raises(CalibrationSpecError, match=r"closest: links.spindle_head.conductance"):
        free_parameters(spec, {"parameters": {"links.spindle_hed.conductance": "fixed"}})
    with pytest.raises(CalibrationSpecError, match=r"calibration.kinds.gain.factor: 0.5"):
        free_parameters(spec, {"kinds": {"gain": {"factor": 0.5}}})
    spec["calibration"] = {"kinds": {"capacity": "fixed"}}
    assert load_machine(spec).spec["calibration"] == {"kinds": {"capacity": "fixed"}}


def test_cli_writes_outputs_refuses_nonempty_dir_and_names_empty_columns(truth_recording, tmp_path, capsys):
    cols = dict(truth_recording.columns)
    cols["table_c"] = np.full(len(truth_recording), np.nan)
    csv = tmp_path / "rec.csv"
    write_recording_csv(csv, truth_recording.time_s, cols)
    out = tmp_path / "cal"
    argv = ["--twin", str(TWIN), "--recording", str(csv), "--out", str(out), "--quiet", "--max-nfev", "8"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "simulated h/s" in printed
    for f in ("twin_calibrated.yaml", "report.md", "report.json", "channels.png", "parameters.png"):
        assert (out / f).is_file(), f
    rep = json.loads((out / "report.json").read_text())
    assert "table_c" not in rep["channels"]
    assert any("table_c" in n for n in rep["notes"])
    assert "sensors.table.bias: sensor not in the recording" in rep["fixed"]
    load_machine(out / "twin_calibrated.yaml")
    assert main(argv) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(argv + ["--force"]) == 0
