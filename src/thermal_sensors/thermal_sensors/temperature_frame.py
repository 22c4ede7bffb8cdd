"""From a source's raw sample to the published frame: gain/offset correction, then status.

The frame is the plain-data content of a ``TemperatureArray`` message; the node only
copies it into the message.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_sensors.sensor_config import SensorConfig
from thermal_sensors.sensor_status import SensorStatus, SensorStatusTracker, StatusRule
from thermal_sensors.temperature_source import RawSample


@dataclass
class TemperatureFrame:
    t_s: float
    sensor_ids: tuple[str, ...]
    temperatures_degc: np.ndarray
    status: np.ndarray            # uint8 SensorStatus codes
    reasons: list[str]            # why a sensor is not OK ("" when OK)

    def same_as(self, other: "TemperatureFrame", atol: float = 1e-9) -> bool:
        """Same instant, ids, statuses and values (NaN where the other has NaN)."""
        return (abs(self.t_s - other.t_s) <= 1e-9 and self.sensor_ids == other.sensor_ids
                and np.array_equal(self.status, other.status)
                and np.allclose(self.temperatures_degc, other.temperatures_degc,
                                atol=atol, rtol=0.0, equal_nan=True))


class TemperatureFrameBuilder:
    """Calibrates raw samples and tracks each sensor's status across samples."""

    def __init__(self, config: SensorConfig):
        self.config = config
        self.trackers = [SensorStatusTracker(StatusRule(
            range_lo_degc=s.range_degc[0], range_hi_degc=s.range_degc[1],
            stale_after_s=s.stale_after_s, stale_tolerance_degc=s.stale_tolerance_degc,
            max_age_s=config.max_age_s)) for s in config.sensors]

    def build(self, sample: RawSample) -> TemperatureFrame:
        n = len(self.config.sensors)
        if len(sample.values_degc) != n:
            raise ValueError(f"sample has {len(sample.values_degc)} values, the configuration "
                             f"has {n} sensors")
        values = np.full(n, np.nan)
        status = np.zeros(n, np.uint8)
        reasons = []
        for i, (spec, tracker) in enumerate(zip(self.config.sensors, self.trackers)):
            corrected = float(spec.gain_offset.apply(sample.values_degc[i]))
            v, st = tracker.update(sample.t_s, corrected, bool(sample.read_ok[i]),
                                   float(sample.acquired_t_s[i]), sample.reasons[i])
            values[i] = v
            status[i] = int(st)
            reasons.append("" if st == SensorStatus.OK else tracker.last_reason)
        return TemperatureFrame(sample.t_s, self.config.sensor_ids, values, status, reasons)
