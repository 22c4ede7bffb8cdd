"""Calibrating first does not hide physics: a parameter pushed to the builder's tolerance bound
or a calibrated residual that stays structured sends the search on, and the report says
"beyond the builder's tolerance" or names the mechanism, never only ``mis-calibrated``."""
from __future__ import annotations

import copy
import json
import pathlib

import numpy as np

from thermal_eval.diagnose.concealed import operating_programme
from thermal_twin.calibrate.bounds import Param
from thermal_twin.calibrate.fit import Estimate
from thermal_twin.diagnose.calibrated import at_bound
from thermal_twin.diagnose.diagnosis import _answer, diagnose
from thermal_twin.diagnose.report import write_report
from thermal_twin.diagnose.report_check import check_report
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()


class _Res:
    def __init__(self, estimates):
        self.estimates = estimates


def test_at_bound_lists_only_parameters_pushed_to_a_bound():
    door = Param("links.door.conductance", "conductance", ("links", "door", "conductance"), 10.0, 7.0, 13.0, False)
    bias = Param("sensors.t4.bias", "bias", ("sensors", "t4", "bias"), 0.0, -0.5, 0.5, False)
    res = _Res([Estimate(door, 12.99, (12.5, 13.0)), Estimate(bias, 0.1, (0.0, 0.2))])
    b = at_bound(res)
    assert [d["name"] for d in b] == ["links.door.conductance"]
    assert abs(b[0]["change_pct"] - 29.9) < 0.01 and b[0]["bounds"] == [7.0, 13.0]


def test_the_answer_is_never_mis_calibrated_when_a_parameter_sits_at_its_bound_or_structure_remains():
    cal = {"used_as_base": True, "mis_calibrated": [{"name": "x"}], "holdout_improvement_pct": 80.0,
           "at_bound": [{"name": "links.door.conductance"}], "residual_structured": []}
    assert _answer([], [], cal, 5.0) == "beyond-tolerance"
    # structure nothing recorded predicts is no evidence of missing physics: none, not mis-calibrated
    cal.update(at_bound=[], residual_structured=[{"channel": "t4_c"}], used_as_base=False)
    assert _answer([], [], cal, 5.0) == "none"
    cal.update(residual_structured=[], used_as_base=True)
    assert _answer([], [], cal, 5.0) == "mis-calibrated"


def test_a_link_far_beyond_its_tolerance_is_named_not_soaked_up(tmp_path):
    true = copy.deepcopy(SPEC)
    true["links"]["table_air"]["conductance"] *= 2.5        # the builder's tolerance is +-30 %
    rec = simulate(true, operating_programme(SPEC, hours=48.0, step_s=300.0, seed=2), seed=2).to_recording()
    d = diagnose(SPEC, rec, calibrate=True)
    rep = d.report
    assert rep["answer"] != "mis-calibrated"
    assert "links.table_air.conductance" in [b["name"] for b in rep["calibration"]["at_bound"]]
    assert rep["answer"] == "ambient_coupling" and rep["selected"][0]["target"] == "table"
    write_report(rep, d.series, tmp_path, rerun=False)
    md = (tmp_path / "report.md").read_text()
    assert "**beyond the builder's tolerance**: `links.table_air.conductance` moved 6 -> 7.8 W/K (+30 %)" in md
    assert check_report(md, json.loads((tmp_path / "report.json").read_text())) == []
    assert np.isfinite(rep["calibration"]["adoption_test"]["holdout_improvement_pct"])
