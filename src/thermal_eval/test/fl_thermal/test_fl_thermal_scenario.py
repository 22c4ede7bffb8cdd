"""The FL_THERMAL spindle programme lives with the dataset and reaches the twin as a plug-in scenario."""
import inspect

import numpy as np
import pytest

import thermal_twin.sim.scenarios as twin_scenarios
from thermal_comp_common.recording_csv import read_recording_csv
from thermal_eval.fl_thermal.scenario import (FL_THERMAL_PROGRAMME, SCENARIO, ProgrammeError,
                                              programme_from_speed)
from thermal_twin.sim.scenarios import SCENARIOS, make_timeline, scenario_names


def _recording(shared_dir):
    return read_recording_csv(shared_dir / "data" / "fl_thermal" / "fl_thermal.csv")


def test_the_programme_is_the_one_the_recordings_speed_column_gives(shared_dir):
    rec = _recording(shared_dir)
    assert programme_from_speed(rec.time_s, rec.columns["spindle_rpm"]) == [
        (float(t), float(v)) for t, v in FL_THERMAL_PROGRAMME]


def test_the_twin_serves_the_plug_in_scenario_row_for_row_like_the_recording(shared_dir):
    assert SCENARIOS["fl-thermal-programme"] is SCENARIO
    assert "fl-thermal-programme" in scenario_names("spindle-stand")
    tl = make_timeline("spindle-stand", "fl-thermal-programme", seed=0)
    rec = _recording(shared_dir)
    np.testing.assert_array_equal(tl.time_s, rec.time_s)
    np.testing.assert_array_equal(tl.values["spindle_rpm"], rec.columns["spindle_rpm"])


def test_the_twin_module_holds_no_fl_thermal_code():
    src = inspect.getsource(twin_scenarios)
    assert "FL_THERMAL" not in src and "11115" not in src


def test_a_speed_column_with_gaps_is_named():
    with pytest.raises(ProgrammeError, match="speed"):
        programme_from_speed([0.0, 15.0, 30.0], [0.0, np.nan, 100.0])
    with pytest.raises(ProgrammeError, match="shapes"):
        programme_from_speed([0.0, 15.0], [0.0])
    assert programme_from_speed([0.0, 15.0, 30.0], [0.0, 0.0, 5.0]) == [(0.0, 0.0), (30.0, 5.0)]
