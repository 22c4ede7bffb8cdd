"""Issue 19 item 6 on the real FL_THERMAL recording (slow: one calibration and five
diagnoses of the 46 h recording, about 15 min on a loaded 2-core machine).

What holds is asserted; what the issue asks and this finder does not yet do on this
recording is an ``xfail(strict=True)`` with the measured reason, so that it turns into a
failure the day it starts to hold (then drop the mark). The table is printed and is the
one in docs/diagnose.md.
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
@pytest.mark.xfail(strict=True, reason="measured: the calibrated spindle-stand keeps a large discrepancy of its "
                                       "own on ch5 (tilt channel); the finder names elastic_gain on ch5 first "
                                       "whatever mechanism was removed (docs/diagnose.md, item 6 table)")
def test_the_removed_mechanism_is_named_first_with_its_parameter_within_30_pct(table):
    for r in table["rows"]:
        assert r["target_ok"], r
        assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r
