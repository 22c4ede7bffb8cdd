"""model_temperatures: only an OK, finite reading reaches a model; the codes are the message's."""
from __future__ import annotations

import math

from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.sensor_readings import STATUS_FAILED, STATUS_OK, model_temperatures


def test_the_status_codes_are_those_of_the_message():
    msg = msg_definitions.typestore().types["thermal_comp_msgs/msg/TemperatureArray"]
    assert (STATUS_OK, STATUS_FAILED) == (msg.STATUS_OK, msg.STATUS_FAILED)


def test_a_reading_is_used_only_with_status_ok_and_a_finite_value():
    temps, excluded = model_temperatures(
        ["a", "b", "c", "d", "e"], [20.5, 21.0, 22.0, math.inf, math.nan], [STATUS_OK, 1, STATUS_FAILED, STATUS_OK, STATUS_OK])
    assert temps["a"] == 20.5
    assert all(math.isnan(temps[s]) for s in "bcde")
    assert excluded == ["b", "c", "d", "e"]
