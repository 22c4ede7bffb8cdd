"""Temperature sensors of the twin: placement, first-order lag, gain/bias, noise, quantisation.

A sensor sees a weighted sum of node and boundary temperatures (placement between bodies,
or a difference such as a coolant inlet-outlet delta), filtered by a first-order lag
(exact for a value held over the step), then ``reading = gain * lagged + bias + noise``,
rounded to the resolution (e.g. 1 degC motor sensors). Noise comes from the generator the
caller passes, so a seed reproduces the readings.
"""
from __future__ import annotations

import numpy as np

from thermal_twin.machine.schema import Machine


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
        self._lagged: np.ndarray | None = None

    def true_values(self, node_temps: np.ndarray, boundary_temps: np.ndarray) -> np.ndarray:
        """What each sensor location really has (no lag, no sensor errors)."""
        return self.weights @ np.concatenate([node_temps, boundary_temps])

    def reset(self) -> None:
        self._lagged = None

    def read(self, node_temps: np.ndarray, boundary_temps: np.ndarray, dt_since_last: float,
             rng: np.random.Generator | None) -> np.ndarray:
        """Readings now; ``dt_since_last`` is the time since the previous call (lag filter)."""
        true = self.true_values(node_temps, boundary_temps)
        if self._lagged is None:
            self._lagged = true.copy()
        else:
            with np.errstate(divide="ignore", over="ignore"):
                a = np.where(self.lag_s > 0, np.exp(-dt_since_last / np.where(self.lag_s > 0, self.lag_s, 1.0)), 0.0)
            self._lagged = a * self._lagged + (1.0 - a) * true
        r = self.gain * self._lagged + self.bias
        if rng is not None and np.any(self.noise_std > 0):
            r = r + self.noise_std * rng.standard_normal(len(r))
        q = self.resolution > 0
        if np.any(q):
            r = r.copy()
            r[q] = np.round(r[q] / self.resolution[q]) * self.resolution[q]
        return r
