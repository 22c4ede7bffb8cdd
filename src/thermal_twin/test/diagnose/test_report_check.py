"""report.md never claims more than report.json: every number derives from the JSON and no
line claims a held-out improvement the report's own channel table contradicts."""
from __future__ import annotations

import copy
import json
import pathlib

import numpy as np
import pytest

from thermal_twin.calibrate.bounds import free_parameters
from thermal_eval.diagnose.concealed import HiddenEffect, OutOfVocabulary, concealed_recording
from thermal_twin.diagnose.diagnosis import diagnose
from thermal_twin.diagnose.report import DiagnosisSeries, write_report
from thermal_twin.diagnose.report_check import check_report, contradicted_claims, underived_numbers
from thermal_twin.machine.schema import load_machine

TWIN = pathlib.Path(__file__).parent / "mini_mill.yaml"


def _channel(before: float, after: float, unit: str = "degC") -> dict:
    return {"unit": unit, "rmse_before": before, "rmse_after": after, "holdout_rmse_before": before,
            "holdout_rmse_after": after, "noise_sigma": 0.05, "ljung_box": {"p_value": 0.01, "white": False},
            "drift": {"slope_per_h": 0.001}, "spectral_peaks": [], "cross_correlation": []}


def _report_t11() -> dict:
    """The over-claim: an unnamed term on T11_c with 98.4 % while the table says 3.92 -> 10.8 K."""
    return {"twin": "rig", "recording": "rec", "split": {"train_end_s": 72000.0, "holdout_start_s": 72300.0,
                                                          "end_s": 108000.0, "holdout_fraction": 1 / 3},
            "channels": {"T11_c": _channel(3.92, 10.8), "T12_c": _channel(0.8, 0.7)},
            "windows": [], "regime_effects": [], "hypotheses": [], "selected": "none",
            "unnamed": [{"effect": "unnamed", "channel": "T11_c", "formula": "T11_c += +0.1 +0.02*t_h [degC]",
                         "terms": [], "offset": 0.1, "nearest_vocabulary_word": "sensor_bias",
                         "holdout_improvement_pct": 98.4, "p_value": 1e-5, "holm_pass": True}],
            "answer": "unnamed", "calibration": None, "augmented_twin": None,
            "criteria": {"multiple_testing": "Holm"}, "notes": []}


def _series(report: dict) -> DiagnosisSeries:
    t = np.arange(0.0, 108001.0, 300.0)
    z = {c: np.zeros(t.size) for c in report["channels"]}
    return DiagnosisSeries(t, z, z, z, 72300.0, dt_s=300.0)


def test_the_old_unnamed_claim_against_a_worse_channel_table_fails():
    rep = _report_t11()
    old_line = ("- **unnamed** (outside the vocabulary; nearest word: sensor_bias): "
                "`T11_c += +0.1 +0.02*t_h [degC]`; held-out improvement 98.4 %")
    problems = contradicted_claims(old_line, rep)
    assert problems and "3.92 -> 10.8" in problems[0]


def test_a_number_the_json_does_not_hold_fails_and_names_do_not_count():
    rep = _report_t11()
    assert underived_numbers("`T11_c` held-out RMSE 3.92 -> 10.8 degC over 20 h", rep) == []
    bad = underived_numbers("`T11_c` improves by 57.3 %", rep)
    assert len(bad) == 1 and bad[0].startswith("57.3")


def test_the_writer_states_the_channel_table_and_passes_the_check(tmp_path):
    rep = _report_t11()
    write_report(copy.deepcopy(rep), _series(rep), tmp_path, rerun=False)
    md = (tmp_path / "report.md").read_text()
    assert check_report(md, json.loads((tmp_path / "report.json").read_text())) == []
    assert "`T11_c` held-out RMSE 3.92 -> 10.8 degC (**worse** than the twin as given)" in md


@pytest.mark.parametrize("hidden,oov", [([HiddenEffect("door_event", "head", "door_open", (30.0,))], ()),
                                        ([], [OutOfVocabulary("sensor_drift", "table", 0.01)])])
def test_a_real_report_md_derives_from_its_json(tmp_path, hidden, oov):
    spec = load_machine(TWIN).to_dict()
    rec, _ = concealed_recording(spec, hidden, hours=36.0, step_s=300.0, seed=11, oov=oov)
    d = diagnose(spec, rec)
    assert d.report["answer"] == ("door_event" if hidden else "unnamed")
    write_report(d.report, d.series, tmp_path, rerun=False)
    md = (tmp_path / "report.md").read_text()
    assert check_report(md, json.loads((tmp_path / "report.json").read_text())) == []


def test_a_source_coefficient_is_printed_per_input_unit_power_not_watts():
    units = {p.name: p.unit for p in free_parameters(load_machine("spindle-stand").to_dict())}
    assert units["sources.motor_losses.coefficient"] == "W per (1/min)^1.2"
    assert units["links.shaft_air.varies_with.spindle_rpm.per_unit"] == "W/K per (1/min)^0.8"
    assert units["links.motor_shaft.conductance"] == "W/K"
