"""Status flags: stuck -> stale, outside the range -> out of range, read error -> failed."""
from __future__ import annotations

import math

import numpy as np
import pytest

from thermal_sensors.gain_offset import GainOffset
from thermal_sensors.sensor_config import parse_sensor_config
from thermal_sensors.sensor_status import SensorStatus, SensorStatusTracker, StatusRule
from thermal_sensors.temperature_frame import TemperatureFrameBuilder
from thermal_sensors.temperature_source import RawSample

RULE = StatusRule(range_lo_degc=0.0, range_hi_degc=50.0, stale_after_s=60.0,
                  stale_tolerance_degc=0.05, max_age_s=30.0)


def test_stuck_value_becomes_stale_after_the_configured_time_and_recovers_on_change():
    tr = SensorStatusTracker(RULE)
    out = [tr.update(t, 21.0 + (0.01 if t % 20 else 0.0))[1] for t in range(0, 130, 10)]
    # changes of 0.01 are within the 0.05 tolerance: unchanged since t=0
    assert out[:7] == [SensorStatus.OK] * 7            # t = 0..60: not longer than 60 s
    assert out[7:] == [SensorStatus.STALE] * 6         # t = 70..120
    v, st = tr.update(130.0, 21.5)
    assert (v, st) == (21.5, SensorStatus.OK)
    assert tr.update(190.0, 21.5)[1] == SensorStatus.OK
    assert tr.update(191.0, 21.5)[1] == SensorStatus.STALE


def test_stale_disabled_with_zero():
    tr = SensorStatusTracker(StatusRule(0.0, 50.0, stale_after_s=0.0))
    assert {tr.update(t, 20.0)[1] for t in np.arange(0, 1e5, 1e3)} == {SensorStatus.OK}


@pytest.mark.parametrize("value,status", [(-0.1, SensorStatus.OUT_OF_RANGE), (0.0, SensorStatus.OK),
                                          (50.0, SensorStatus.OK), (50.01, SensorStatus.OUT_OF_RANGE)])
def test_range_limits_are_inclusive(value, status):
    v, st = SensorStatusTracker(RULE).update(0.0, value)
    assert st == status and v == value      # an out-of-range value is published, flagged


@pytest.mark.parametrize("value,read_ok,acquired", [
    (21.0, False, 0.0),            # read error / timeout
    (math.nan, True, 0.0),         # NaN
    (math.inf, True, 0.0),
    (21.0, True, -30.001),         # no fresh reading within max_age_s
])
def test_failed_reads_publish_nan(value, read_ok, acquired):
    v, st = SensorStatusTracker(RULE).update(0.0, value, read_ok, acquired, reason="timeout")
    assert st == SensorStatus.FAILED and math.isnan(v)


def test_failed_beats_out_of_range_beats_stale():
    tr = SensorStatusTracker(RULE)
    for t in range(0, 100, 10):
        tr.update(float(t), 70.0)
    assert tr.update(100.0, 70.0)[1] == SensorStatus.OUT_OF_RANGE   # stuck and out of range
    assert tr.update(110.0, 70.0, read_ok=False)[1] == SensorStatus.FAILED


def test_a_repeated_old_reading_is_not_ok_forever():
    """A source that keeps handing out its last reading: ok while young, failed once old."""
    tr = SensorStatusTracker(RULE)
    assert tr.update(100.0, 21.0, acquired_t_s=100.0)[1] == SensorStatus.OK
    assert tr.update(130.0, 21.0, acquired_t_s=100.0)[1] == SensorStatus.OK       # 30 s: limit
    v, st = tr.update(131.0, 21.0, acquired_t_s=100.0)
    assert st == SensorStatus.FAILED and math.isnan(v) and "31 s old" in tr.last_reason


def test_time_going_backwards_resets_the_history():
    tr = SensorStatusTracker(RULE)
    for t in range(0, 200, 10):
        tr.update(float(t), 21.0)
    assert tr.update(200.0, 21.0)[1] == SensorStatus.STALE
    assert tr.update(0.0, 21.0)[1] == SensorStatus.OK     # a replay restarted


def test_gain_offset_correction_and_two_point_fit():
    cal = GainOffset(offset_degc=-0.4, gain=1.002)
    assert cal.apply(25.0) == pytest.approx(1.002 * 25.0 - 0.4)
    assert cal.invert(cal.apply(31.7)) == pytest.approx(31.7)
    assert math.isnan(cal.apply(math.nan))
    fit = GainOffset.from_two_points(0.3, 0.0, 99.5, 100.0)
    assert fit.apply(0.3) == pytest.approx(0.0) and fit.apply(99.5) == pytest.approx(100.0)
    with pytest.raises(ValueError, match="gain"):
        GainOffset(gain=0.0)
    with pytest.raises(ValueError, match="equal"):
        GainOffset.from_two_points(1.0, 0.0, 1.0, 100.0)


def test_frame_builder_corrects_before_checking_the_range():
    config = parse_sensor_config({"sensors": [
        {"id": "a", "range_degc": [0, 30], "calibration": {"offset_degc": 2.0, "gain": 1.0}},
        {"id": "b", "range_degc": [0, 30]}]})
    b = TemperatureFrameBuilder(config)
    sample = RawSample(5.0, np.array([29.0, 29.0]), np.array([True, True]), np.array([5.0, 5.0]), ["", ""])
    frame = b.build(sample)
    assert list(frame.temperatures_degc) == [31.0, 29.0]
    assert list(frame.status) == [SensorStatus.OUT_OF_RANGE, SensorStatus.OK]
    assert "31 degC outside the range [0, 30]" in frame.reasons[0] and frame.reasons[1] == ""
    with pytest.raises(ValueError, match="3 values"):
        b.build(RawSample(6.0, np.zeros(3), np.ones(3, bool), np.zeros(3), [""] * 3))


def test_status_codes_are_the_message_constants():
    from thermal_comp_msgs.msg import TemperatureArray as T
    assert [SensorStatus.OK, SensorStatus.STALE, SensorStatus.OUT_OF_RANGE, SensorStatus.FAILED] == \
        [T.STATUS_OK, T.STATUS_STALE, T.STATUS_OUT_OF_RANGE, T.STATUS_FAILED]
