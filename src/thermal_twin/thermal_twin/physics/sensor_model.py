"""Temperature sensors of the twin: placement, first-order lag, gain/bias, noise, quantisation.

A sensor sees a weighted sum of node and boundary temperatures (placement between bodies,
or a difference such as a coolant inlet-outlet delta), filtered by a first-order lag
(exact for a value held over the step), then ``reading = gain * lagged + bias + drift * t + noise``
(``drift_k_per_h`` since t = 0 of the clock), rounded to the resolution (e.g. 1 degC motor sensors). Noise comes from the generator the
caller passes, so a seed reproduces the readings.
"""
from __future__ import annotations

import numpy as np

from thermal_twin.machine.schema import Machine, SensorSpec


class SensorBank:
    """All sensors of a machine, evaluated together; keeps the lag filter state."""

    def __init__(self, machine: Machine, node_names: list[str], boundary_names: list[str]):
        self.ids = list(machine.sensors)
        self.columns = [machine.sensors[s].column for s in self.ids]
        places = {n: i for i, n in enumerate(node_names + boundary_names)}
        self.weights = np.zeros((len(self.ids), len(places)))
        for j, sid in enumerate(self.ids):
            for place, w in machine.sensors[sid].weights:
                self.weights[j, places[place]] += w
        spec = [machine.sensors[s] for s in self.ids]
        self.noise_std = np.array([s.noise_std for s in spec])
        self.resolution = np.array([s.resolution for s in spec])
        self.lag_s = np.array([s.lag_s for s in spec])
        self.bias = np.array([s.bias for s in spec])
        self.gain = np.array([s.gain for s in spec])
        self.drift_k_per_s = np.array([s.drift_k_per_h for s in spec]) / 3600.0
        self._lagged: np.ndarray | None = None

    def true_values(self, node_temps: np.ndarray, boundary_temps: np.ndarray) -> np.ndarray:
        """What each sensor location really has (no lag, no sensor errors)."""
        return self.weights @ np.concatenate([node_temps, boundary_temps])

    def reset(self) -> None:
        self._lagged = None

    def read(self, node_temps: np.ndarray, boundary_temps: np.ndarray, dt_since_last: float,
             rng: np.random.Generator | None, t_s: float) -> np.ndarray:
        """Readings at clock time ``t_s``; ``dt_since_last`` is the time since the previous call
        (lag filter)."""
        true = self.true_values(node_temps, boundary_temps)
        if self._lagged is None:
            self._lagged = true.copy()
        else:
            with np.errstate(divide="ignore", over="ignore"):
                a = np.where(self.lag_s > 0, np.exp(-dt_since_last / np.where(self.lag_s > 0, self.lag_s, 1.0)), 0.0)
            self._lagged = a * self._lagged + (1.0 - a) * true
        r = self.gain * self._lagged + self.bias + self.drift_k_per_s * t_s
        if rng is not None and np.any(self.noise_std > 0):
            r = r + self.noise_std * rng.standard_normal(len(r))
        q = self.resolution > 0
        if np.any(q):
            r = r.copy()
            r[q] = np.round(r[q] / self.resolution[q]) * self.resolution[q]
        return r


def drift_offsets(machine: Machine, time_s: np.ndarray) -> dict[str, np.ndarray]:
    """The drift part of each drifting sensor's reading (by column) at clock times ``time_s``,
    for evaluators that compute readings without it."""
    t = np.asarray(time_s, float)
    return {s.column: s.drift_k_per_h * t / 3600.0 for s in machine.sensors.values() if s.drift_k_per_h}


def read_backwards(spec: SensorSpec | None, reading, t_s):
    """The temperature a reading stands for: ``(reading - bias - drift * t) / gain``, so a
    diagnosed bias or drift of a sensor reaches what the twin is driven by."""
    if spec is None or (spec.bias == 0.0 and spec.gain == 1.0 and spec.drift_k_per_h == 0.0):
        return reading
    return (reading - spec.bias - spec.drift_k_per_h * np.asarray(t_s, float) / 3600.0) / spec.gain
