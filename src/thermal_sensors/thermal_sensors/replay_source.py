"""The ``replay`` source: a recording CSV (the shared format) played in simulated time.

At time t the sample holds the newest row with ``time_s <= t`` (rows are instants of
acquisition, so a held row carries its own acquisition time and ages honestly).
Sensors are matched by their CSV column (``channel`` + ``_c``); empty/NaN cells are
failed reads.
"""
from __future__ import annotations

import pathlib

import numpy as np

from thermal_sensors.sensor_config import SensorConfig, SensorConfigError, config_from_channels
from thermal_sensors.temperature_source import RawSample
from thermal_comp_common.recording_csv import Recording, read_recording_csv


class ReplaySource:
    def __init__(self, recording: Recording, config: SensorConfig):
        missing = [(i, s.csv_column) for i, s in enumerate(config.sensors)
                   if s.csv_column not in recording.columns]
        if missing:
            i, col = missing[0]
            raise SensorConfigError(
                f"sensors[{i}].channel: column {col!r} is not in {recording.source or 'the recording'} "
                f"(temperature columns: {recording.names('sensor')})")
        self.config = config
        self.sensor_ids = config.sensor_ids
        self.recording = recording
        self.time_s = recording.time_s
        self._data = np.column_stack([recording.columns[s.csv_column] for s in config.sensors])

    @classmethod
    def from_csv(cls, path: str | pathlib.Path, config: SensorConfig | None = None) -> "ReplaySource":
        """Open a CSV; without a configuration every ``*_c`` column becomes a sensor."""
        rec = read_recording_csv(path)
        if config is None:
            config = config_from_channels(rec.names("sensor"))
        return cls(rec, config)

    @property
    def start_s(self) -> float:
        return float(self.time_s[0])

    @property
    def end_s(self) -> float:
        return float(self.time_s[-1])

    def instants(self, period_s: float = 0.0) -> np.ndarray:
        """The instants a time master steps through: every row (0) or every ``period_s``."""
        if period_s < 0 or not np.isfinite(period_s):
            raise ValueError(f"period_s: {period_s!r} must be >= 0")
        if period_s == 0:
            return self.time_s.copy()
        n = int(np.floor((self.end_s - self.start_s) / period_s + 1e-9)) + 1
        return self.start_s + period_s * np.arange(n)

    def sample(self, t_s: float) -> RawSample:
        n = len(self.sensor_ids)
        k = int(np.searchsorted(self.time_s, t_s + 1e-9, side="right")) - 1
        if k < 0:
            return RawSample.all_failed(t_s, n, f"replay starts at t={self.start_s:g} s")
        row = self._data[k].astype(float)
        ok = np.isfinite(row)
        acquired = np.where(ok, self.time_s[k], -np.inf)
        # a failed cell: the last good acquisition before it is not the current value
        reasons = ["" if good else f"no value in the recording at t={self.time_s[k]:g} s" for good in ok]
        return RawSample(t_s, np.where(ok, row, np.nan), ok, acquired, reasons)

    def close(self) -> None:
        pass
