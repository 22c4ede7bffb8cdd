"""replay: one set of config keys, components from the recording, the CD's limit, the overwrite
rule and the warnings of a short or harmful replay."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.replay.cli import main
from thermal_eval.replay.config_keys import CD_MAX_NODES, ConfigKeyError, canonical_config, replay_warnings


def test_one_set_of_keys_with_the_old_ones_as_deprecated_aliases():
    cfg, notes = canonical_config("talc", {"sensors": ["a"], "components": ["z"]}, ["z_um"])
    assert cfg == {"input_names": ["a"], "component_names": ["z"]} and notes == []
    cfg, notes = canonical_config("agp", {"input_names": ["a"], "component_names": ["z"]}, ["z_um"])
    assert cfg == {"sensors": ["a"], "components": ["z"]}
    assert len(notes) == 2 and all("deprecated" in n for n in notes)
    with pytest.raises(ConfigKeyError, match="both 'input_names' and 'sensors'"):
        canonical_config("cd", {"input_names": ["a"], "sensors": ["b"]}, [])


def test_components_default_to_the_recordings_error_columns():
    cfg, notes = canonical_config("talc", {}, ["ch1_um", "E_X0C"])
    assert cfg["component_names"] == ["ch1", "E_X0C"] and "ch1, E_X0C" in notes[0]


def test_a_characteristic_diagram_beyond_the_grid_limit_is_reduced_and_said():
    cfg, notes = canonical_config("cd", {"components": ["z"], "max_inputs": 6}, [])
    assert cfg["max_inputs"] == 4 and 5 ** 4 <= CD_MAX_NODES < 5 ** 5
    assert "max_inputs 6" in notes[0] and "reduced to max_inputs 4" in notes[0]
    cfg, notes = canonical_config("cd", {"components": ["z"], "max_inputs": 2, "n_intervals": 8}, [])
    assert cfg["max_inputs"] == 2 and notes == []
    with pytest.raises(ConfigKeyError, match="max_inputs"):
        canonical_config("cd", {"components": ["z"], "max_inputs": "six"}, [])


def test_warnings_of_a_short_or_harmful_replay():
    never = {"compensation_steps": 0, "duration_h": 2.0, "calibration_h": float("nan"), "components": {}}
    assert "did not leave its calibration phase in 2.00 h" in replay_warnings(never)[0]
    short = {"compensation_steps": 10, "duration_h": 10.0, "calibration_h": 9.0,
             "components": {"z": {"p99": 3.0, "p99_uncompensated": 1.0, "unit": "um"},
                            "x": {"p99": 0.5, "p99_uncompensated": 1.0, "unit": "um"}}}
    w = replay_warnings(short)
    assert "only 10 %" in w[0] and w[1].startswith("component z: the compensation made it worse") and len(w) == 2
    fine = dict(short, calibration_h=2.0, components={})
    assert replay_warnings(fine) == []


def test_an_existing_json_is_refused_unless_force(tmp_path, capsys):
    t = np.arange(0.0, 3600.0 * 2, 60.0)
    rec = tmp_path / "rec.csv"
    write_recording_csv(rec, t, {"a_c": 20 + 0.001 * t / 60, "ch1_um": 0.01 * t / 60})
    out = tmp_path / "r.json"
    out.write_text("{}")
    assert main([str(rec), "--model", "agp", "--json", str(out), "--no-progress"]) == 3
    assert "--force" in capsys.readouterr().err and out.read_text() == "{}"


def test_several_recordings_are_replayed_alone_and_pooled(tmp_path, capsys):
    import json
    from thermal_eval.replay.runs import pooled_components
    t = np.arange(0.0, 3600.0 * 30, 60.0)
    for k in range(2):
        a = 20 + np.sin(t / 20000 + k)
        write_recording_csv(tmp_path / "runs" / f"day{k}.csv", t, {"a_c": a, "ch1_um": 3 * (a - a[0])})
    out = tmp_path / "o" / "all.json"
    assert main([str(tmp_path / "runs"), "--model", "agp", "--json", str(out), "--no-progress"]) == 0
    f = json.loads(out.read_text())
    assert [r["name"] for r in f["runs"]] == ["day0", "day1"] and f["pooled"]["ch1"]["runs"] == 2
    one = [json.loads((tmp_path / "o" / f"all.day{k}.json").read_text()) for k in range(2)]
    assert f["pooled"]["ch1"]["rows"] == sum(o["scored_steps"] for o in one)
    assert "pooled over 2 runs" in capsys.readouterr().out
    assert pooled_components([], None) == {}
    assert main([str(tmp_path / "runs"), "--model", "agp", "--json", str(out), "--no-progress"]) == 3
