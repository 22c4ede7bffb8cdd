"""Issue 19 item 6, the speedless bearing row with the speed's scale anchored by the coolant
balance (thermal_twin.input_scale_anchor; the rule and figures in docs/calibrate.md). Slow:
one calibration, two rounds of speed estimate and diagnosis of the 46 h recording: 176 s
measured on 2 cores under load 10-15 (2 passed, 1 strict xfail). What the issue asks and does not hold is an
``xfail(strict=True)`` with the measured reason."""
from __future__ import annotations

import json

import pytest

from thermal_eval.fl_thermal_scale_anchor import run

pytestmark = [pytest.mark.slow, pytest.mark.timeout(2400)]


@pytest.fixture(scope="module")
def row(shared_dir):
    out = run(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv", progress=None)
    print(json.dumps({k: v for k, v in out.items() if k != "rounds"}, default=str))
    return out


def test_the_anchored_speed_has_the_deleted_speeds_scale(row):
    # measured: round 1 mean 1687 against 1619 1/min, motor 30.2 against 31.4 W (unanchored 5066, 114 W)
    r1 = row["rounds"][0]
    assert r1["speed_mean"] == pytest.approx(r1["true_speed_mean"], rel=0.15)
    assert r1["speed_max"] <= r1["true_speed_max"]
    assert r1["motor_heat_mean_w"] == pytest.approx(r1["motor_heat_true_mean_w"], rel=0.25)
    assert row["balance"]["fit_corr"] > 0.7


def test_the_bearing_source_is_named_first_and_restores_the_fit(row):
    # measured: heat_source:front_bearing first (66.9 % against the periodic load's 62.2 %), restored 124 %
    assert row["first"] == "heat_source:front_bearing"
    assert row["converged"]
    assert row["restored_pct"] >= 80.0
    assert row["heat_w"]["fitted_mean_w"] == pytest.approx(row["heat_w"]["calibrated_mean_w"], rel=0.3)


@pytest.mark.xfail(strict=True, reason="measured 33 %: P_max is the heat at the estimated maximum (4219 1/min: "
                                       "30-min blocks smooth the speed's peaks), the reference at 5000")
def test_the_bearing_source_p_max_within_30_percent(row):
    assert row["rel_error_pct"] <= 30.0
