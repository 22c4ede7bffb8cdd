"""The ``twin`` source: raw readings of machine_sim's ``twin/sensor_readings``.

The node feeds each received message (ids, values, status, stamp) to :meth:`accept`;
configured sensors are matched by their ``channel`` to the twin's sensor ids. A channel
the twin does not publish, a NaN, or a twin status FAILED is a failed read. The twin's
other status flags are not trusted: status is recomputed like for every source.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from thermal_sensors.sensor_config import SensorConfig
from thermal_sensors.temperature_source import RawSample

TWIN_STATUS_FAILED = 3  # TemperatureArray.STATUS_FAILED


class TwinSource:
    def __init__(self, config: SensorConfig):
        self.config = config
        self.sensor_ids = config.sensor_ids
        n = len(config.sensors)
        self._values = np.full(n, np.nan)
        self._ok = np.zeros(n, bool)
        self._acquired = np.full(n, -np.inf)
        self._reasons = ["no twin reading received yet"] * n

    def accept(self, t_s: float, twin_ids: Sequence[str], values_degc: Sequence[float],
               status: Sequence[int] | None = None) -> None:
        """Take one ``twin/sensor_readings`` message stamped ``t_s``."""
        if len(values_degc) != len(twin_ids) or (status is not None and len(status) and
                                                  len(status) != len(twin_ids)):
            raise ValueError(f"twin/sensor_readings at t={t_s}: {len(twin_ids)} ids, "
                             f"{len(values_degc)} values, {len(status or [])} status entries")
        index = {sid: k for k, sid in enumerate(twin_ids)}
        for i, spec in enumerate(self.config.sensors):
            k = index.get(spec.channel)
            if k is None:
                self._ok[i], self._values[i] = False, math.nan
                self._reasons[i] = f"twin publishes no sensor {spec.channel!r}"
                continue
            v = float(values_degc[k])
            failed = bool(status is not None and len(status) and status[k] == TWIN_STATUS_FAILED)
            if failed or not math.isfinite(v):
                self._ok[i], self._values[i] = False, math.nan
                self._reasons[i] = f"twin sensor {spec.channel!r} failed"
                continue
            self._ok[i], self._values[i], self._acquired[i] = True, v, t_s
            self._reasons[i] = ""

    def sample(self, t_s: float) -> RawSample:
        return RawSample(t_s, self._values.copy(), self._ok.copy(), self._acquired.copy(),
                         list(self._reasons))

    def close(self) -> None:
        pass
