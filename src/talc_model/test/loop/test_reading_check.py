"""Readings flagged OK but not finite or outside the plausible range are refused (ROS-free
check) and, in the model node, never reach the model: excluded like a failed sensor, counted,
logged once per burst, on /diagnostics."""
from __future__ import annotations

import math

import pytest

from thermal_comp_common.sensor_readings import PLAUSIBLE_RANGE_DEGC, STATUS_FAILED
from talc_model.loop.reading_check import ReadingCheck
from test_model_node_stamps import T0, _state, sim_node  # noqa: F401  (the node fixture)

FORGED = [math.nan, math.inf, -math.inf, 1e9, -273.0]


@pytest.mark.parametrize("value", FORGED)
def test_an_implausible_reading_flagged_ok_is_refused(value):
    check = ReadingCheck()
    v = check.check(60.0, ["a", "b"], [value, 21.0], [0, 0])
    assert v.invalid == ["a"] and v.status == [STATUS_FAILED, 0] and v.log and "a=" in v.text
    kind = "non_finite" if not math.isfinite(value) else "out_of_range"
    assert check.counts[kind] == 1 and check.refused == 1


def test_the_range_bounds_are_valid_and_a_non_ok_reading_is_the_publishers():
    check = ReadingCheck()
    lo, hi = PLAUSIBLE_RANGE_DEGC
    v = check.check(0.0, ["lo", "hi", "failed"], [lo, hi, math.nan], [0, 0, STATUS_FAILED])
    assert v.invalid == [] and not v.log and check.refused == 0


def test_one_line_per_burst_and_the_burst_ends_after_quiet_clean_messages():
    check = ReadingCheck(quiet=3)
    logs = [check.check(t, ["a"], [1e9], [0]).log for t in range(5)]
    assert logs == [True, False, False, False, False] and check.refused == 5
    ends = [check.check(t, ["a"], [20.0], [0]).burst_over for t in range(3)]
    assert ends == [False, False, True] and not check.in_burst
    assert check.check(9.0, ["a"], [math.nan], [0]).log                # a new burst is said again


@pytest.mark.parametrize("bad", [(1.0, 1.0), (math.nan, 10.0), (0.0, math.inf)])
def test_the_range_is_validated(bad):
    with pytest.raises(ValueError, match="range_degc"):
        ReadingCheck(bad)


@pytest.mark.ros
def test_forged_readings_flagged_ok_never_reach_the_model(sim_node):  # noqa: F811
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray
    node, _, set_clock = sim_node
    seen = []
    step = node.loop.step
    node.loop.step = lambda t, temps, *rest: (seen.append(dict(temps)), step(t, temps, *rest))[1]
    for k, (a, b) in enumerate([(20.0, 21.0), (math.nan, 1e9), (math.inf, 21.0), (20.5, 21.5)]):
        t = T0 + 300.0 * k
        set_clock(t)
        node._on_machine_state(_state(t))
        node._on_temperatures(TemperatureArray(header=Header(stamp=s_to_stamp(t)), sensor_ids=["a", "b"],
                                               temperatures_degc=[a, b], status=[0, 0]))
    assert [len(s) for s in seen] == [2, 2, 2, 2] and node.loop.t_last == T0 + 900.0
    assert seen[0] == {"a": 20.0, "b": 21.0} and seen[3] == {"a": 20.5, "b": 21.5}
    assert all(math.isnan(v) for v in seen[1].values()) and math.isnan(seen[2]["a"]) and seen[2]["b"] == 21.0
    lines = [w for w in node.warnings if "flagged OK refused" in w]
    assert len(lines) == 1 and "a=nan" in lines[0] and "b=1000000000.0" in lines[0]
    status = next(s for s in node.diag.statuses() if s.name.endswith(": readings"))
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == b"\x01" and values["readings_refused_non_finite"] == "2"
    assert values["readings_refused_out_of_range"] == "1" and values["plausible_range_degc"] == "-50..150"
