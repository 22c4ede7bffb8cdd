"""The slow part of a model's error between probes, as a scalar Kalman filter.

Between probes an adaptive model's error has a slow part b(t) (a heat flow the model misses, a
drifting reference: an Ornstein-Uhlenbeck state with time constant ``bias_time_constant_s``)
and a fast part (transients) that a probe catches at a random phase. The best estimate of b
between probes is a scalar Kalman filter: at a probe b += K (r - b), K = P / (P + noise_ratio);
between probes b decays by exp(-dt / tau) and P relaxes to 1 (P in units of var(b)).
``noise_ratio`` -> 0 with a long tau is "hold the last probe's offset"; a large ``noise_ratio``
trusts the open-loop model. Derivation and figures: docs/fl_thermal.md. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np


class SlowErrorError(ValueError):
    """Bad input to the slow-error filter; the message names the argument and value."""


@dataclass(frozen=True)
class SlowErrorFilter:
    """The scalar Kalman filter of one channel's slow model error (see the module docstring)."""

    bias_time_constant_s: float = 4 * 3600.0   # Ornstein-Uhlenbeck time constant of the slow error
    noise_ratio: float = 1.0                    # fast model-error variance / slow-error variance

    def __post_init__(self) -> None:
        v = self.bias_time_constant_s
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise SlowErrorError(f"bias_time_constant_s: {v!r} must be a finite number > 0")
        v = self.noise_ratio
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise SlowErrorError(f"noise_ratio: {v!r} must be a finite number >= 0")


def slow_error_compensation(time_s: np.ndarray, y: np.ndarray, gp_mean: np.ndarray, probe_rows: Sequence[int],
                            post_probe_mean: np.ndarray, start: int, stop: int, flt: SlowErrorFilter) -> np.ndarray:
    """One channel's compensation GP mean + slow error b on rows [start, stop) (NaN elsewhere).

    b starts at 0 with variance 0 (the GP was just fitted on the calibration points); at a probe
    row the residual y - (GP mean after the probe's update) feeds the scalar Kalman filter of
    :class:`SlowErrorFilter`, effective from the next row (the probe row itself
    was compensated before its probe); between probes b decays with exp(-dt / tau).
    """
    t = np.asarray(time_s, dtype=float)
    comp = np.full(t.size, np.nan)
    b, var, t_b = 0.0, 0.0, float(t[start - 1])
    bounds = list(probe_rows) + [stop - 1]
    lo = start
    for i, hi in enumerate(bounds):
        rows = np.arange(lo, hi + 1)
        a = np.exp(-(t[rows] - t_b) / flt.bias_time_constant_s)
        comp[rows] = gp_mean[rows] + b * a
        if i == len(probe_rows):
            break
        a_k = a[-1]
        b, var = b * a_k, var * a_k * a_k + (1.0 - a_k * a_k)
        denom = var + flt.noise_ratio
        gain = var / denom if denom > 0 else 1.0
        b, var, t_b = b + gain * (y[hi] - post_probe_mean[i] - b), var * (1.0 - gain), float(t[hi])
        lo = hi + 1
    # rows after the probe row are compensated with the updated b; the GP mean after a probe
    # is already in gp_mean (replay_agp re-predicts from the next row)
    return comp
