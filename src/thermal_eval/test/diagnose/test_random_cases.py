"""The drawn concealed-effect cases: reproducible one by one, covering every preset and kind,
with the drawn size reached and the scoring rules of the random bench."""
import json

import numpy as np
import pytest

from thermal_eval.diagnose.random_bench import markdown, parse, rescore
from thermal_eval.diagnose.random_cases import KINDS, OOV_KINDS, draw_case
from thermal_eval.diagnose.random_recording import case_recording
from thermal_eval.diagnose.random_score import judge, score
from thermal_twin.machine.presets import preset_names


def test_a_case_is_drawn_alone_the_same_whatever_was_drawn_before():
    later_first = [draw_case(7, i) for i in (5, 3, 9)]
    in_order = {i: draw_case(7, i) for i in range(10)}
    assert [c.label for c in later_first] == [in_order[i].label for i in (5, 3, 9)]
    assert draw_case(7, 3).noise == in_order[3].noise
    assert draw_case(8, 3).label != in_order[3].label or draw_case(8, 3).noise != in_order[3].noise


def test_draws_cover_every_preset_kind_noise_colour_and_oov_kind():
    cases = [draw_case(123, i) for i in range(300)]
    assert {c.twin for c in cases} == set(preset_names())
    assert {c.kind for c in cases} == set(KINDS)
    assert {c.noise["colour"] for c in cases} == {"white", "ar1", "random_walk"}
    assert {o.kind for c in cases for o in c.oov} == set(OOV_KINDS)
    assert any(c.onset_h > 0 for c in cases) and any(c.noise["clock_offset_s"] != 0 for c in cases)
    assert all(len({h.effect for h in c.hidden}) == 2 for c in cases if c.kind == "two")


def test_bad_seed_is_refused_with_its_value():
    with pytest.raises(ValueError, match="seed: -1"):
        draw_case(-1, 0)


def test_recording_is_reproducible_and_reaches_the_drawn_size():
    case = next(c for c in (draw_case(5, i) for i in range(60))
                if c.kind == "named" and c.hidden[0].effect in ("heat_source", "sensor_bias", "elastic_gain"))
    rec1, truth1 = case_recording(case)
    rec2, truth2 = case_recording(case)
    assert np.array_equal(rec1.time_s, rec2.time_s)
    for c in rec1.columns:
        assert np.array_equal(rec1.columns[c], rec2.columns[c])
    # amplitude-linear effects reach the drawn size within 25 % (a few nonlinear ones fall short)
    assert truth1["size_measured"] == pytest.approx(case.size, rel=0.25)
    assert truth1["keys"] == [h.key for h in truth1["hidden"]]


def _outcome(kind, true, answer, selected, unnamed=(), params=None, values=None):
    return {"kind": kind, "true_keys": [":".join(k.split(":")[:2]) for k in true],
            "true_types": [k.split(":")[0] for k in true], "answer": answer, "selected": list(selected),
            "selected_params": params or [[1.0]] * len(selected), "true_values": values or [[1.0]] * len(true),
            "unnamed": list(unnamed), "oov": [], "size_measured": 3.0, "wall_s": 1.0, "cpu_s": 1.0,
            "holdout_cut_pct": 50.0, "worse_channels": []}


def test_judge_counts_extras_exactness_and_both_effects():
    o = _outcome("named", ["heat_source:table"], "heat_source", ["heat_source:table", "periodic_load:bed"],
                 params=[[30.0], [5.0]], values=[[40.0]])
    j = judge(o)
    assert j["first"] and j["exact"] and j["extra"] == 1 and j["param_err"] == pytest.approx(0.25)
    assert judge(_outcome("none", [], "none", [], unnamed=["0.1*t_h"]))["extra"] == 1
    assert not judge(_outcome("unnamed", [], "elastic_gain", ["elastic_gain:E/x"]))["right"]
    two = _outcome("two", ["coolant:bed", "door_event:head"], "door_event", ["door_event:head", "coolant:bed"])
    assert judge(two)["both"] and judge(two)["first"]
    fig = score([o, two, _outcome("none", [], "periodic_load", ["periodic_load:bed"])], wall_s=60.0)
    assert fig["single_exact_target_pct"] == 100.0 and fig["none_answered_pct"] == 0.0
    assert fig["two_both_found_pct"] == 100.0 and fig["cases_per_minute"] == 3.0
    assert fig["confusion"]["none"] == {"periodic_load": 1}
    twin_target = _outcome("named", ["ambient_coupling:column_top"], "ambient_coupling",
                           ["ambient_coupling:spindle_body"])
    assert not judge(twin_target)["in_set"]
    twin_target["selected_sets"] = [["ambient_coupling:column_top"]]
    assert judge(twin_target)["in_set"] and not judge(twin_target)["exact"]


def test_the_markdown_tables_are_the_figures():
    o = _outcome("named", ["heat_source:table"], "heat_source", ["heat_source:table"])
    shifted = _outcome("none", [], "unnamed", [], unnamed=["t1_c += 0.1*d(t2_c)/dt"])
    o["noise"] = {"colour": "white", "clock_offset_s": 0.0}
    shifted["noise"] = {"colour": "ar1", "clock_offset_s": 300.0}
    fig = score([o, shifted], wall_s=120.0)
    assert fig["per_condition"]["clock offset"] == {"n": 1, "right_pct": 0.0, "unnamed_without_oov": "1/1"}
    assert fig["per_condition"]["no clock offset"]["right_pct"] == 100.0
    md = markdown({"seed": 1000, "first": 0, "n": 2, "calibrate": False, "jobs": 2, "wall_s": 120.0,
                   "load_average_1min": 3.0}, fig)
    assert "| single_exact_target_pct | 100 |" in md and "| none_answered_pct | 0 |" in md
    assert "| clock offset | 1 | 0 | 1/1 |" in md
    assert "| heat_source | 1 | 100 | 100 |" in md and "seed 1000, cases 0-1" in md
    with pytest.raises(SystemExit):
        parse(["--random", "0"])


def test_rescore_pools_runs_of_one_seed_and_refuses_mixed_ones(tmp_path):
    o = _outcome("named", ["heat_source:table"], "heat_source", ["heat_source:table"])
    o["noise"] = {"colour": "white", "clock_offset_s": 0.0}
    meta = {"seed": 1000, "first": 0, "n": 1, "calibrate": False, "jobs": 2, "wall_s": 30.0, "load_average_1min": 2.0}
    for first in (0, 1):
        (tmp_path / f"r{first}.json").write_text(json.dumps({"meta": {**meta, "first": first}, "outcomes": [o]}))
    md = rescore([tmp_path / "r0.json", tmp_path / "r1.json"], tmp_path / "pool.md")
    assert "seed 1000, cases 0-1 (2 cases" in md and (tmp_path / "pool.md").read_text() == md
    (tmp_path / "r2.json").write_text(json.dumps({"meta": {**meta, "seed": 7}, "outcomes": [o]}))
    with pytest.raises(ValueError, match="mix seeds"):
        rescore([tmp_path / "r0.json", tmp_path / "r2.json"])
