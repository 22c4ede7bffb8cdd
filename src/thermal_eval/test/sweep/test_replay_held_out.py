"""thermal-comp replay on a user's recording: measured errors in a bag (--errors-topic), a held-out
scoring window (--score-from-h), components named as their columns, misses named with the closest."""
from __future__ import annotations

import json

from thermal_eval.replay.cli import main as replay_main

TALC = ["--model", "talc", "--set", "preset=table_6_3_A", "--set", "input_names=[ambient, ws_mwf, c_coolant_delta]",
        "--set", "cp_length_h=4", "--no-progress"]


def test_a_bag_of_measured_errors_replays_with_its_topic(short_csv, tmp_path, capsys):
    from thermal_comp_common.bags.csv_to_bag import csv_to_bag
    bag = tmp_path / "measured_bag"
    csv_to_bag(short_csv, bag, errors_as="measured", every=2)
    out = tmp_path / "m.json"
    assert replay_main([str(bag), *TALC, "--hours", "2", "--json", str(out)]) == 2
    assert "errors/ground_truth" in capsys.readouterr().err
    assert replay_main([str(bag), *TALC, "--errors-topic", "errors/measured", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["errors_topic"] == "errors/measured" and data["compensation_steps"] > 0


def test_the_held_out_window_scores_only_its_rows(short_csv, tmp_path):
    whole, held = tmp_path / "whole.json", tmp_path / "held.json"
    assert replay_main([str(short_csv), *TALC, "--json", str(whole)]) == 0
    assert replay_main([str(short_csv), *TALC, "--score-from-h", "10.5", "--json", str(held)]) == 0
    w, h = json.loads(whole.read_text()), json.loads(held.read_text())
    assert w["scored_steps"] == w["compensation_steps"] and w["scored_from_h"] is None
    assert 0 < h["scored_steps"] < h["compensation_steps"] == w["compensation_steps"]
    assert h["scored_from_h"] == 10.5 and h["components"]["E_X0C"]["p99"] != w["components"]["E_X0C"]["p99"]
    assert replay_main([str(short_csv), *TALC, "--score-from-h", "99", "--json", str(tmp_path / "x.json")]) == 2


def test_a_component_may_be_named_as_its_column_and_a_miss_names_the_closest(short_csv, tmp_path, capsys):
    from thermal_comp_common.recording_csv import read_recording_csv
    cols = read_recording_csv(short_csv).names("error")
    col = next(c for c in cols if c.startswith("E_X0C"))
    out = tmp_path / "c.json"
    assert replay_main([str(short_csv), *TALC, "--hours", "6", "--set", f"component_names=[{col}]",
                        "--json", str(out)]) == 0
    assert list(json.loads(out.read_text())["components"]) == [col]
    assert replay_main([str(short_csv), *TALC, "--hours", "6", "--set", "component_names=[E_X0D]",
                        "--json", str(out)]) == 2
    assert f"closest: '{col}'" in capsys.readouterr().err
