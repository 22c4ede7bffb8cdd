"""The one interface every temperature source implements, and the sample it returns.

A source delivers raw (uncalibrated) readings of the configured sensors, in the order of
the sensor configuration; calibration and status are applied afterwards, the same way
for every source (:mod:`thermal_sensors.temperature_frame`).

Sources: ``twin`` (:mod:`thermal_sensors.twin_source`), ``replay``
(:mod:`thermal_sensors.replay_source`), ``modbus`` (:mod:`thermal_sensors.modbus_source`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

SOURCE_KINDS = ("twin", "replay", "modbus")


@dataclass
class RawSample:
    """Raw readings of all configured sensors as known at time ``t_s``.

    ``values_degc[i]`` is NaN where ``read_ok[i]`` is false; ``acquired_t_s[i]`` is when
    sensor i was last read successfully (same clock as ``t_s``; -inf if never);
    ``reasons[i]`` says why a read failed.
    """

    t_s: float
    values_degc: np.ndarray
    read_ok: np.ndarray
    acquired_t_s: np.ndarray
    reasons: list[str]

    @classmethod
    def all_failed(cls, t_s: float, n: int, reason: str) -> "RawSample":
        return cls(t_s, np.full(n, np.nan), np.zeros(n, bool), np.full(n, -np.inf), [reason] * n)


@runtime_checkable
class TemperatureSource(Protocol):
    """A provider of raw readings for the configured sensors."""

    #: sensor ids, in the order of the values of every sample
    sensor_ids: tuple[str, ...]

    def sample(self, t_s: float) -> RawSample:
        """The newest readings known at ``t_s`` (never blocks on I/O)."""
        ...

    def close(self) -> None:
        """Release connections and threads."""
        ...
