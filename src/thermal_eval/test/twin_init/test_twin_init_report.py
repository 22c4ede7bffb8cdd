"""docs/twin_init.md's tables come from the bench's JSON: every ratio and MAE printed is the
JSON's, rounded; the nmv5000 description of the bench is a valid description; the bench runs the
sections it is given."""
from __future__ import annotations

import argparse

import pytest

from thermal_twin.identify import load_description

from thermal_eval.twin_init.bench import options
from thermal_eval.twin_init.fl_case import DESCRIPTION as FL_DESCRIPTION
from thermal_eval.twin_init.report import INIT, NO_PRIOR, TYPE, before_after_table, markdown
from thermal_eval.twin_init.units_case import DESCRIPTION

COMPS = {"E_X0C": 1.234, "E_Y0C": 2.0, "E_Z0T": 3.0, "E_R0T": 4.0, "E_A0C": 5.0, "E_B0C": 6.0, "E_C0C": 7.0}
HELD = {c: {"twin": 0.5, "training mean": 1.5, "static regression": 0.75} for c in COMPS}


def _doc():
    unit = {"seed": 22, "kind": "links", "truth": "links x2", "hidden_bodies": 2, "probes_first_day": 58,
            "ratios": {NO_PRIOR: 2.0634, INIT: 0.4567, TYPE: 0.2841},
            "components_p99": {INIT: COMPS}, "init_held_out_rmse": HELD,
            "wall_s": {"twin_init": 17.7, "prior": 15.8}, "twin_simulated_h_per_s": 900.0}
    fl = {"hidden_bodies": 1, "wall_s": 100.0, "twin_simulated_h_per_s": 570.0,
          "rows": {"ch1": {"twin init (open loop)": {"test_mae_um": 1.9876, "validation_mae_um": 2.5},
                           "lagged ridge": {"test_mae_um": 1.1, "validation_mae_um": 1.2}}}}
    adopt = {"seed": 23, "kind": "extra_source", "hidden_bodies": 3, "adopted": False, "reason": "worse on E_Z0T",
             "ratios": {"no prior running on": 1.0646, "init-twin prior from 48 h, always": 1.9039,
                        "init-twin prior from 48 h if adopted": 1.0646}}
    return {"units": [unit], "adoption": [adopt], "fl_thermal": fl}


def test_the_tables_print_the_json_figures():
    md = markdown(_doc())
    assert "| #22 links | links x2 | 2 | 58 | 2.063 | **0.457** | 0.284 | 1.23 / 2.00 / 3.00 / 4.00 |" in md
    assert "1.988 [2.500]" in md and "1.100 [1.200]" in md
    assert "| #23 extra_source | 3 | no | worse on E_Z0T | 1.065 | 1.904 | 1.065 |" in md
    assert "0 of 1 at most 0.5" not in md and "1 of 1 at most 0.5" in md


def test_before_and_after_are_matched_by_unit_and_counted():
    after = _doc()["units"]
    before = [{**after[0], "hidden_bodies": 1, "ratios": {NO_PRIOR: 2.0634, INIT: 0.6017}},
              {**after[0], "seed": 99, "ratios": {NO_PRIOR: 1.0, INIT: 0.1}}]      # no after row: left out
    lines = before_after_table(after, before)
    assert "| #22 links | 1 -> 2 | 2.063 | 0.602 | **0.457** | -0.145 |" in lines
    assert lines[-1] == ("- 1 units: before 0.602-0.602 (mean 0.602, 0 at most 0.5), after 0.457-0.457 "
                         "(mean 0.457, 1 at most 0.5); better on 1, worse on 0; worse than no prior on 0")


def test_the_bench_descriptions_are_valid():
    nmv = load_description(str(DESCRIPTION))
    assert nmv.hall == "ambient" and nmv.inputs["c_speed_rpm"].moves
    fl = load_description(str(FL_DESCRIPTION))
    assert fl.boundaries["coolant"] == "sensor:t4" and fl.cooled["coolant"] == ["motor", "housing"]


def test_the_fl_adaptive_table_prints_the_json_figures_and_a_units_free_doc_works():
    cell = {"twin adaptive": [0.8612, 0.588], "best data-only adaptive (arx_simulation)": [1.074, 0.913],
            "best data-only adaptive of the channel": [0.675, 0.73], "best of the channel": "lagged_ridge_inputs",
            "holding": [2.979, 1.094], "twin open loop": [1.225, 1.88], "lagged ridge open loop": [3.697, 2.111],
            "training mean": [6.558, 2.013], "static regression": [9.209, 6.07], "twin choice": None}
    ad = {"best data-only row": "arx_simulation", "channels": {"ch1": cell}, "probings_per_h": {"a": 0.972},
          "better_than_best_row": {"mean_of_windows": 1, "test": 1, "validation": 1},
          "better_than_best_of_each_channel": {"mean_of_windows": 0, "test": 0, "validation": 1},
          "better_than_each_row": {"arx_simulation": 1, "lagged_ridge_inputs": 0}}
    doc = _doc()
    doc["units"], doc["adoption"] = [], []
    doc["fl_thermal"]["adaptive"] = ad
    md = markdown(doc)
    assert "nmv5000 units" not in md and "0.97 at most" in md
    assert ("| ch1 | **0.861 [0.588]** | 1.074 [0.913] | 0.675 [0.730] `lagged_ridge_inputs` | 2.979 [1.094] | "
            "1.225 [1.880] | 3.697 [2.111] | 6.558 [2.013] | 9.209 [6.070] |") in md
    assert "below the best data-only adaptive row of each channel on 0 of 1 channels" in md
    assert "`lagged_ridge_inputs` 0" in md


def test_the_bench_takes_its_sections_and_refuses_an_unknown_one(capsys):
    opts = options(argparse.Namespace(extra=["--sections=fl", "--csv=/x.csv"]))
    assert opts.sections == ["fl"] and opts.csv == "/x.csv"
    assert options(argparse.Namespace(extra=[])).sections == ["units", "adoption", "fl"]
    with pytest.raises(SystemExit):
        options(argparse.Namespace(extra=["--sections=fl,unit"]))
    assert "'unit' is not one of units, adoption, fl" in capsys.readouterr().err


def test_the_bench_takes_seeds_and_kinds_and_refuses_unknown_ones(capsys):
    opts = options(argparse.Namespace(extra=["--seeds=30,31", "--kinds=links,gain"]))
    assert opts.seeds == (30, 31) and opts.kinds == ("links", "gain")
    default = options(argparse.Namespace(extra=[]))
    assert default.seeds is None and default.kinds is None
    for bad, said in (("--kinds=links,lnks", "'lnks' is not one of"), ("--seeds=3x", "'3x' must be"),
                      ("--seeds=,", "names no seed")):
        with pytest.raises(SystemExit):
            options(argparse.Namespace(extra=[bad]))
        assert said in capsys.readouterr().err
