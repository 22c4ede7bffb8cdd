"""Concealed mechanisms named back on the real FL_THERMAL recording (slow: one calibration of the
``fl-thermal-rig`` preset, a screen of its 54 mechanisms with their identifiability (157 twin
runs), seven diagnoses of the 46 h recording and, for the two speedless rows (the bearing source
and the motor jacket), two rounds of speed estimate and diagnosis each (input_alternation, the
speed's scale anchored by the coolant balance): 240 s measured on 2 cores under load 2.5 before
the jacket's speedless row was added; the two speedless rows alone take 83 s of diagnosis each
at load 1-5, over 600 s under load 13-16).

The mechanisms are chosen by the recording, not by the finder: every mechanism of the
calibrated twin is removed and scored with the calibrated twin alone, and the rule of
:func:`thermal_eval.fl_thermal.mechanisms.select` (named by a word of the vocabulary, held-out
SSE x1.2 or more, calibrated value not at a bound) picks the ones diagnosed. What holds is
asserted; what the issue asks and does not hold on this recording is an
``xfail(strict=True)`` with the measured reason, so that it turns into a failure the day it
starts to hold (then drop the mark). The tables are printed and are those of docs/diagnose.md.
"""
from __future__ import annotations

import json

import pytest

from thermal_eval.fl_thermal.ablation import markdown, run, speedless_mechanisms
from thermal_eval.fl_thermal.mechanisms import all_mechanisms, screen_markdown
from thermal_twin.machine.schema import load_machine

#: the module fixture (calibration, screen, seven diagnoses, two speedless alternations) is paid by
#: the first test: 240 s at load 2.5, but over the suite's 600 s default at load 13-16 (measured)
pytestmark = pytest.mark.timeout(2400)

BEARING = "source front_bearing_friction (spindle_rpm-driven)"
JACKET = "link motor_coolant (motor-coolant)"
HOUSING = "link housing_headstock (housing-headstock)"
CH5 = "thermo-elastic term ch5_um/headstock"


#: the finder's never-worse rule on this real recording (docs/diagnose.md, Limits): the removed
#: bearing source fits best but leaves three temperatures worse beyond chance alignment with the
#: twin's own residual there, as the calibrated source itself does
NEVER_WORSE = ("measured: heat_source:front_bearing fits best (held-out 65 %, P_max 227 / 275 W) but leaves "
               "t3, t15 and t16 worse beyond chance alignment with the twin's own residual (the calibrated "
               "source does too: held-out RMSE 0.80 -> 1.48, 0.59 -> 1.35, 1.60 -> 4.72 K against the ablated "
               "twin), so it ranks 4th and periodic_load:headstock is named first (restored 100 %)")


@pytest.fixture(scope="module")
def table(shared_dir):
    # speedless="rule": the bearing source and the docs' rule's pick (the motor jacket) without speed
    out = run(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv", progress=None, speedless="rule")
    print(screen_markdown(out["screen"]))
    print(markdown(out))
    print(json.dumps(out["rows"], default=str))
    return out


def test_the_asserted_speedless_row_keeps_every_speed_driven_source():
    # the rule of docs/diagnose.md (real recording, speed deleted): after the bearing source, the first
    # chosen mechanism whose removal leaves both speed-driven sources (bearing, motor) in the twin
    spec = load_machine("fl-thermal-rig").to_dict()
    by = {m.label: m for m in all_mechanisms(spec, 5000.0)}
    motor = by["source motor_losses (spindle_rpm-driven)"]
    chosen = [motor, by[BEARING], by[JACKET], by[HOUSING]]
    assert [m.label for m in speedless_mechanisms(chosen, spec, "bearing")] == [BEARING]
    assert [m.label for m in speedless_mechanisms(chosen, spec, "rule")] == [BEARING, JACKET]
    assert [m.label for m in speedless_mechanisms(chosen, spec, "all")] == [BEARING, JACKET, motor.label, HOUSING]
    with pytest.raises(ValueError, match="speedless='every'"):
        speedless_mechanisms(chosen, spec, "every")


def _row(table, label, recording="FL_THERMAL"):
    return next(r for r in table["rows"] if r["mechanism"] == label and r["recording"] == recording)


@pytest.mark.slow
def test_the_recording_supports_the_bearing_source_and_the_conduction_paths(table):
    # the screen uses the calibrated twin only; measured ratios 2.56 (bearing), 31.2 (motor jacket)
    chosen = [r["mechanism"] for r in table["rows"] if r["selected_by_rule"] and r["recording"] == "FL_THERMAL"]
    assert BEARING in chosen and JACKET in chosen and len(chosen) >= 4, chosen
    ratio = {r["mechanism"]: r["ratio"] for r in table["screen"]}
    assert ratio[JACKET] > 10 and ratio[BEARING] > 2, ratio
    # no ambient link and no sensor lag is supported on this recording (measured <= 1.07, 1.00)
    assert all(r["ratio"] < 1.2 for r in table["screen"]
               if (r["expected"] or "").startswith(("ambient_coupling", "time_lag"))), ratio


@pytest.mark.slow
def test_every_ablation_is_diagnosed_and_what_is_adopted_improves_the_held_out_fit(table):
    # on the recording the finder saw (the speedless row: with the estimated speed)
    rows = table["rows"]
    assert len(rows) == 9 and table["calibration"]["free_parameters"] > 0
    # the speedless row's reference is the calibrated twin on the real recording
    for r in rows:
        assert r["holdout_sse_ablated"] > 0 and r["holdout_sse_after"] <= r["holdout_sse_ablated"] * 1.0001, r


@pytest.mark.slow
@pytest.mark.parametrize("label", [pytest.param(BEARING, marks=pytest.mark.xfail(strict=True, reason=NEVER_WORSE)), JACKET,
                                   HOUSING, CH5])
def test_a_supported_mechanism_is_named_first_recovered_within_30_pct_and_the_fit_restored(table, label):
    # measured (with fl_thermal_rig's contacts): bearing 227 / 275 W (17 %), restored
    # 107 %; jacket 30.5 / 31.7 W/K (4 %), 100 %; housing-headstock 31.5 / 29.1 W/K (8 %), 100 %;
    # ch5/headstock re-added from zero 15.4 / 14 um/K (10 %), 103 % (its reference is at its x4 bound)
    r = _row(table, label)
    assert r["holdout_sse_ablated"] > 1.5 * r["holdout_sse_calibrated"], r     # the recording sees it
    assert r["target_ok"], r
    assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r
    assert r["restored_pct"] is not None and r["restored_pct"] >= 80.0, r


@pytest.mark.slow
def test_with_contacts_a_removed_path_comes_back_as_itself_not_a_neighbour(table):
    # without contacts (every pair proposed) bearing-housing came back as bearing-column, housing-
    # headstock as bearing-headstock, headstock-column as a convection. Measured with contacts:
    # each named first as itself, restoring 100 / 100 / 97 %; G 32.8 / 23.8 (38 %) for
    # bearing-housing and 13.9 / 20.2 (31 %) for headstock-column, outside the 30 %
    for label in ("link front_housing (front_bearing-housing)", HOUSING, "link headstock_column (headstock-column)"):
        r = _row(table, label)
        assert r["target_ok"] and r["restored_pct"] >= 80.0, r
    assert not _row(table, CH5)["selected_by_rule"]          # at its x4 calibration bound


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured (docs/diagnose.md, \"Proof on the real recording\"): with contacts every "
                                       "removed path but motor-shaft is named first as itself, but bearing-"
                                       "housing's G is off 38 % and headstock-column's 31 %; without "
                                       "motor-shaft the finder names a 24 h periodic load on the shaft "
                                       "(the path fits 2nd, G 6.6 / 13.7); without the bearing source a periodic "
                                       "load on the headstock (the source leaves t3, t15, t16 worse)")
def test_every_selected_mechanism_is_named_first_with_its_parameter_within_30_pct(table):
    for r in table["rows"]:
        if r["selected_by_rule"] and r["recording"] == "FL_THERMAL":
            assert r["target_ok"], r
            assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r


@pytest.mark.slow
def test_identifiability_is_decided_for_every_mechanism_with_a_word(table):
    # computed from the calibrated twin alone (fl_thermal_identifiability), before any diagnosis
    for r in table["screen"]:
        assert (r["identifiable"] is None) == (r["expected"] is None), r
        if r["identifiable"] is not None:
            assert r["competitor"] and r["competitor"] != r["expected"] and r["distinct"] >= 0, r
    ident = {r["mechanism"]: r["identifiable"] for r in table["screen"]}
    assert ident[JACKET], ident


@pytest.mark.slow
def test_the_speedless_estimate_follows_the_deleted_speed_with_the_coolant_return_as_a_response(table):
    # the first round's estimate (the ablated twin as given): measured block heat r = 0.57 with
    # the deleted speed's heat, 114 W mean against 106 W (with t4 as the coolant boundary
    # instead: r = -0.45, 46 W); the second round (with the finder's augmented twin) 0.49, 119 W
    e = _row(table, BEARING, "speed deleted, estimated")["alternation"][0]
    assert e["corr_with_true_heat"] > 0.5, e
    assert e["mean_power_w"] == pytest.approx(e["true_mean_power_w"], rel=0.3), e


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured (docs/diagnose.md, \"Proof on the real recording\"): the bearing-housing "
                                       "path is identifiable (its best other word, a bias of t5, leaves 2.1x the "
                                       "calibrated held-out SSE) and is named first, but its G is 32.8 against "
                                       "the calibrated 23.8 W/K (38 %, restoring 100 %)")
def test_every_selected_identifiable_mechanism_is_named_first_with_its_parameter_within_30_pct(table):
    for r in table["rows"]:
        if r["selected_by_rule"] and r["identifiable"] and r["recording"] == "FL_THERMAL":
            assert r["target_ok"], r
            assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r


@pytest.mark.slow
def test_with_the_speed_deleted_the_motor_jacket_is_named_first_within_30_pct_and_the_fit_restored(table):
    # the docs' rule (stated before the run): the support rule's top pick among removals that keep
    # both speed-driven sources. Measured (anchored): named first in both alternation
    # rounds, G 30.0 / 31.7 W/K (5 %), restored 102 %; estimated heat r = 0.54, 109 W mean against
    # the deleted speed's 105 W (unanchored: G 25.4, 20 %, restored 101 %; FL_THERMAL row: 30.5, 4 %)
    r = _row(table, JACKET, "speed deleted, estimated")
    assert r["holdout_sse_ablated"] > 1.5 * r["holdout_sse_calibrated"], r
    assert r["effect_ok"] and r["target_ok"], r
    assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r
    assert r["restored_pct"] is not None and r["restored_pct"] >= 80.0, r
    assert r["estimate"]["converged"], r["alternation"]


@pytest.mark.slow
def test_with_the_speed_deleted_the_anchored_speed_has_the_deleted_speeds_scale(table):
    # the coolant balance (W = 10.6 W/K of t4's rise, fitted on the training rows with the speed)
    # anchors the scale: measured round 1 mean 1687 against 1619 1/min, max 3891 against 5000
    # (unanchored: 5066 mean, 11,683 max)
    assert table["calibration"]["coolant_balance"]["fit_corr"] > 0.7
    for label in (BEARING, JACKET):
        sp = _row(table, label, "speed deleted, estimated")["estimate"]["speed"]
        assert sp["mean"] == pytest.approx(sp["true_mean"], rel=0.15), (label, sp)
        assert sp["max"] <= sp["true_max"], (label, sp)


@pytest.mark.slow
def test_with_the_speed_deleted_the_bearing_source_is_named_first_its_heat_recovered_and_the_fit_restored(table):
    # measured (anchored): heat_source:front_bearing first in both rounds, its mean heat at the
    # estimated speed 81 against the removed source's 74.0 W, restored 125 %
    r = _row(table, BEARING, "speed deleted, estimated")
    assert r["effect_ok"] and r["target_ok"], r
    assert r["estimate"]["converged"], r["alternation"]
    assert r["restored_pct"] is not None and r["restored_pct"] >= 80.0, r
    assert r["heat_w"]["fitted_mean_w"] == pytest.approx(r["heat_w"]["calibrated_mean_w"], rel=0.3), r["heat_w"]


@pytest.mark.slow
def test_with_the_speed_deleted_the_bearing_source_p_max_is_within_30_pct(table):
    # measured: P_max 259.6 / 275.1 W (6 %) at the anchored estimated speed's maximum
    r = _row(table, BEARING, "speed deleted, estimated")
    assert r["rel_error_pct"] is not None and r["rel_error_pct"] <= 30.0, r
