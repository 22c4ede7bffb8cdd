"""Multi-TCP "GPR-offset models" of the lathe thesis (§5.2): Delta_k = e_k - e_base of one tool
position predicted from tool-position temperatures, trained offline and not recalibrated in
production (thesis Ch. 8). The AGP adds them to its base component (docs/agp_cd.md).
No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.agp.gaussian_process import AgpConfigError, ArdGaussianProcess


class OffsetModel:
    """GPR-offset model of one tool position: Delta_k = e_k - e_base from tool temperatures."""

    def __init__(self, component: str, base: str, sensors: Sequence[str], gp: ArdGaussianProcess | None = None):
        self.component = component
        self.base = base
        self.sensors = list(sensors)
        if not self.sensors:
            raise AgpConfigError(f"offset model {component!r}: 'sensors' is empty")
        self.gp = gp or ArdGaussianProcess()

    def fit(self, temperatures: Mapping[str, Sequence[float]], error_k, error_base,
            max_points: int = 1500) -> "OffsetModel":
        """Train offline on a multi-TCP training test (arrays over time). Rows with NaN are
        dropped; long tests are thinned evenly to ``max_points`` (O(N^3) fit)."""
        missing = [s for s in self.sensors if s not in temperatures]
        if missing:
            raise AgpConfigError(f"offset model {self.component!r}: sensors {missing} not in the training data")
        x = np.column_stack([np.asarray(temperatures[s], dtype=float) for s in self.sensors])
        d = np.asarray(error_k, dtype=float) - np.asarray(error_base, dtype=float)
        ok = np.all(np.isfinite(x), axis=1) & np.isfinite(d)
        x, d = x[ok], d[ok]
        if x.shape[0] > max_points:
            keep = np.linspace(0, x.shape[0] - 1, max_points).round().astype(int)
            x, d = x[keep], d[keep]
        self.gp.fit(x, d, warm_start=False)
        return self

    def predict(self, temperatures: Mapping[str, float]) -> tuple[float, float]:
        x = np.array([[float(temperatures.get(s, math.nan)) for s in self.sensors]])
        if not np.all(np.isfinite(x)) or not self.gp.fitted:
            return math.nan, math.nan
        m, s = self.gp.predict(x)
        return float(m[0]), float(s[0])

    def to_state(self) -> dict:
        return {"component": self.component, "base": self.base, "sensors": self.sensors,
                "gp": self.gp.to_state()}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "OffsetModel":
        try:
            return cls(state["component"], state["base"], state["sensors"],
                       ArdGaussianProcess.from_state(state["gp"]))
        except KeyError as exc:
            raise AgpConfigError(f"offset model state: missing key {exc}") from None
