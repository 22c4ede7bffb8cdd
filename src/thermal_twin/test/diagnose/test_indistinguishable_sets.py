"""Effects whose fits this recording cannot tell apart are reported as a set, with what would.

A drawn fe-three-body case conceals an ambient coupling of ``column_top``; the coupling of
``spindle_body`` fits the recording as well (collinear output changes, held-out within 5
points). The adopted effect lists the true one in its set, the channel and regime where the
two differ most, and says that no recorded channel separates them; ``report.md`` prints the
set and every figure it states derives from ``report.json``.
"""
from __future__ import annotations

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_eval.diagnose.random_cases import draw_case, twin_spec
from thermal_eval.diagnose.random_recording import case_recording
from thermal_twin.diagnose.diagnosis import diagnose
from thermal_twin.diagnose.fit import FitProblem, Hypothesis
from thermal_twin.diagnose.report import write_report
from thermal_twin.diagnose.report_check import contradicted_claims, underived_numbers
from thermal_twin.diagnose.search_round import tell_apart


def test_tell_apart_names_the_channel_and_regime_where_two_fits_differ():
    t = np.arange(200) * 300.0
    run = (np.arange(200) // 20) % 2 == 1
    cols = {"spindle_rpm": np.where(run, 8000.0, 0.0), "head_c": np.full(200, 20.0), "table_c": np.full(200, 20.0)}
    p = FitProblem(Recording(t, cols), ["head_c", "table_c"], 200, sigma={"head_c": 0.1, "table_c": 0.1})
    a_change = np.concatenate([np.ones(200), np.zeros(200)])
    b_change = np.concatenate([np.ones(200), 3.0 * run])          # b moves table_c while running
    a = Hypothesis(None, np.zeros(1), {}, 0, 1, 1, 1, 1, 0, None, change=a_change)
    b = Hypothesis(None, np.zeros(1), {}, 0, 1, 1, 1, 1, 0, None, change=b_change)
    way = tell_apart(p, a, b)
    assert way["channel"] == "table_c" and way["recorded_channel_tells_apart"]
    assert way["regime"] == "spindle running" and way["regime_difference_rms_sigma"] > way["difference_rms_sigma"]


def test_an_indistinguishable_target_is_reported_in_the_set_with_what_would_tell_it_apart(tmp_path):
    case = draw_case(0, 16)
    rec, truth = case_recording(case)
    assert truth["keys"] == ["ambient_coupling:column_top:ambient_degc"]
    d = diagnose(twin_spec(case.twin), rec)
    rep = d.report
    first = rep["selected"][0]
    assert first["effect"] == "ambient_coupling"
    others = [w["other"] for w in first["tell_apart"]]
    if first["target"] != "column_top":
        assert "ambient_coupling:column_top:ambient_degc" in others, first
    assert others and all(w["channel"] in rep["channels"] for w in first["tell_apart"])
    write_report(rep, d.series, tmp_path, rerun=False)
    md = (tmp_path / "report.md").read_text()
    assert "indistinguishable on this recording (reported as a set)" in md
    assert underived_numbers(md, rep) == [] and contradicted_claims(md, rep) == []
