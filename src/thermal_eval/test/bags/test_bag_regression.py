"""Regression: every bag in bags/ with a regression.yaml replays through its model exactly as
its golden.json says; differences are reported in words."""
import copy
import json
import pathlib

import numpy as np
import pytest

from thermal_eval.replay import bag_regression as br
from thermal_comp_common.bags import msg_definitions as md
REPO = pathlib.Path(__file__).resolve().parents[4]
BAGS = REPO / "bags"
REGEN = ".venv/bin/python -m thermal_eval.replay.bag_regression bags/{name} --update"


@pytest.mark.parametrize("bag", br.regression_bags(BAGS), ids=lambda p: p.name)
def test_bag_replays_as_golden(bag):
    golden = json.loads(br.golden_path(bag).read_text())
    diff = br.compare(br.replay(bag), golden)
    assert not diff, (f"{bag.name} replay differs from golden.json:\n  " + "\n  ".join(diff)
                      + f"\nIf the change is intended, re-generate: {REGEN.format(name=bag.name)}")


def test_there_are_regression_bags_and_each_is_small_and_documented():
    bags = br.regression_bags(BAGS)
    assert len(bags) >= 3
    readme = (BAGS / "README.md").read_text()
    for b in [p for p in BAGS.iterdir() if p.is_dir()]:
        assert f"`{b.name}`" in readme, f"bags/README.md has no line for {b.name}"
        mcap = sum(f.stat().st_size for f in b.glob("*.mcap"))
        assert 0 < mcap < 1_000_000, (b.name, mcap)


def test_differences_are_described_in_words():
    bag = br.regression_bags(BAGS)[0]
    golden = json.loads(br.golden_path(bag).read_text())
    now = copy.deepcopy(golden)
    comp = sorted(now["predicted"])[0]
    k = next(i for i, v in enumerate(now["predicted"][comp]) if v is not None)
    now["predicted"][comp][k] += 0.5
    dropped = now["probe_times_s"].pop(0)
    now["phase"][-1] = "something_else"
    diff = br.compare(now, golden)
    t = golden["time_s"][k]
    assert any(line.startswith(f"{comp} predicted differs at 1 of") and f"first at t={t:g} s" in line
               for line in diff), diff
    assert f"probing at t={dropped:g} s: golden probed, now it does not" in diff
    assert any(line.startswith("phase differs at 1 steps") for line in diff)
    assert br.compare(golden, golden) == []


def test_machine_state_flattening_is_the_same_for_live_and_bag_messages():
    from thermal_comp_common.machine_inputs import machine_state_inputs
    from thermal_comp_msgs.msg import MachineState
    m = MachineState()
    m.spindle_names, m.spindle_speeds_rpm = ["s1", "s11"], [3500.0, 1000.0]
    m.rotary_axis_names, m.rotary_axis_speeds_rpm = ["C"], [600.0]
    m.axis_names, m.axis_positions = ["X"], [12.5]
    m.drive_names, m.drive_powers_w = ["Z"], [80.0]
    m.coolant_on, m.coolant_temperature_degc, m.door_open, m.machine_busy_probing = True, 22.0, False, True
    live = machine_state_inputs(m)
    assert live["s1_rpm"] == 3500.0 and live["s11_rpm"] == 1000.0 and live["coolant_on"] == 1.0
    # the rosbags-decoded form of the same message (what replay and regression read) flattens alike
    store = md.typestore()
    from rclpy.serialization import serialize_message
    decoded = store.deserialize_cdr(serialize_message(m), "thermal_comp_msgs/msg/MachineState")
    assert machine_state_inputs(decoded) == live


def test_bad_specs_name_the_file_and_key(tmp_path):
    f = tmp_path / "regression.yaml"
    f.write_text("model_kind: talc\n")
    with pytest.raises(br.RegressionError, match="missing key 'model_config'"):
        br.RegressionSpec.load(f)
    f.write_text("model_kind: talc\nmodel_config: {}\nnoise: 1\n")
    with pytest.raises(br.RegressionError, match=r"unknown key\(s\) \['noise'\]"):
        br.RegressionSpec.load(f)
