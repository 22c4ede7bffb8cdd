"""Issue 19 item 6 on the real FL_THERMAL recording (slow: one calibration of the
``fl-thermal-rig`` preset and five diagnoses of the 46 h recording, 8-10 min on a loaded
2-core machine).

What holds is asserted: every ablation is diagnosed, and the speed-driven front-bearing heat
source, removed from the calibrated twin, is named first (effect and node), with its power
within 30 % of the calibrated value, and the held-out fit is restored. What the issue asks
and does not hold on this recording is an ``xfail(strict=True)`` with the measured reason,
so that it turns into a failure the day it starts to hold (then drop the mark). The table is
printed and is the one in docs/diagnose.md.
"""
from __future__ import annotations

import json

import pytest

from thermal_eval.fl_thermal_ablation import markdown, run


@pytest.fixture(scope="module")
def table(shared_dir):
    out = run(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv", progress=None)
    print(markdown(out))
    print(json.dumps(out, default=str))
    return out


@pytest.mark.slow
def test_every_ablation_is_diagnosed_and_what_is_adopted_improves_the_held_out_fit(table):
    # on the recording the finder saw (the speedless row: with the estimated speed)
    rows = table["rows"]
    assert len(rows) == 5 and table["calibration"]["free_parameters"] > 0
    for r in rows:
        assert r["holdout_sse_ablated"] > 0 and r["holdout_sse_after"] <= r["holdout_sse_ablated"] * 1.0001, r


@pytest.mark.slow
def test_the_removed_bearing_heat_source_is_named_first_recovered_within_30_pct_and_the_fit_restored(table):
    r = table["rows"][0]
    assert r["expected"] == "heat_source:front_bearing" and r["recording"] == "FL_THERMAL"
    assert r["holdout_sse_ablated"] > 1.5 * r["holdout_sse_calibrated"], r     # the recording sees it
    assert r["target_ok"], r
    assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r
    assert r["restored_pct"] is not None and r["restored_pct"] >= 80.0, r


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured (docs/diagnose.md, item 6 table): removing the headstock's "
                                       "ambient link or t5's 60 s lag loses no held-out fit on FL_THERMAL (the "
                                       "recording gives no evidence for them), and without the ch5/headstock "
                                       "gain the finder restores the tilt channel through the collinear "
                                       "housing node instead; with the speed deleted, the estimated input goes "
                                       "to the motor source the ablated twin still has and the finder names a "
                                       "periodic load on the headstock")
def test_every_removed_mechanism_is_named_first_with_its_parameter_within_30_pct(table):
    for r in table["rows"]:
        assert r["target_ok"], r
        assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r
