"""Which temperature readings a model may use: the ``TemperatureArray`` contract in one place.

A reading is a model input only with status OK and a finite value; any other reading is NaN,
so the model excludes that sensor and holds its contribution. The codes are the ``STATUS_*``
constants of ``thermal_comp_msgs/TemperatureArray`` (and of ``thermal_sensors.SensorStatus``),
kept here as numbers so ROS-free code needs no generated message classes.
"""
from __future__ import annotations

import math
from typing import Iterable

STATUS_OK = 0
STATUS_FAILED = 3
#: the physical range of a machine-tool temperature reading, degC: a sensor's default measuring
#: range, and what a model accepts from any publisher whatever the status says
PLAUSIBLE_RANGE_DEGC = (-50.0, 150.0)


def model_temperatures(sensor_ids: Iterable[str], temperatures_degc: Iterable[float],
                       status: Iterable[int]) -> tuple[dict[str, float], list[str]]:
    """(sensor id -> value, NaN unless the status is OK and the value finite; the NaN ids in order)."""
    temps: dict[str, float] = {}
    excluded: list[str] = []
    for sid, v, st in zip(sensor_ids, temperatures_degc, status):
        ok = int(st) == STATUS_OK and math.isfinite(v)
        temps[sid] = float(v) if ok else math.nan
        if not ok:
            excluded.append(sid)
    return temps, excluded
