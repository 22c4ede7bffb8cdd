"""Between probes, blend a model's compensation with the last measurement by their uncertainties.

The last measured error drifts away like a random walk (variance ``hold_rate`` x time since);
the model's predictive variance says how far to trust its compensation. The estimate follows
the model where it knows the state and the last measurement right after a probe and in states
the model has not seen. :func:`measured_hold_rate` measures the random-walk rate on calibration
rows (measured, not tuned). Figures: docs/fl_thermal.md. No rclpy here.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

#: Lag over which the random-walk rate is measured on the calibration rows (s): the shortest
#: gap between two measurements of the FL_THERMAL AGP (its sigma_max probes' rate limit).
HOLD_RATE_LAG_S = 600.0


class HoldError(ValueError):
    """Bad input to the uncertainty-weighted hold; the message names the argument and value."""


def uncertainty_weighted_hold(time_s: np.ndarray, y: np.ndarray, compensation: np.ndarray, gp_std: np.ndarray,
                              measured_rows: Sequence[int], start: int, stop: int, hold_rate: float) -> np.ndarray:
    """Blend the model's compensation with the last measured displacement by their uncertainties.

    Between two measurements the displacement is known at the last one, y_p, and drifts away from
    it like a random walk with variance ``hold_rate`` (um^2/h) x the time since; the GP's own
    predictive variance ``gp_std``^2 says how far to trust its compensation c. The estimate is
    y_p + w (c - y_p), w = q dt / (q dt + std^2): the GP where it knows the state (small std),
    the last measurement right after it and where the state is unseen (large std; the GP mean
    swings there). ``hold_rate`` = inf returns c unchanged, 0 holds the last measurement.
    ``measured_rows``: the last calibration probing (< start) and the probe rows; a probe row
    itself was compensated before its probe. Rows outside [start, stop) are NaN.
    """
    if not (isinstance(hold_rate, (int, float)) and not math.isnan(hold_rate) and hold_rate >= 0):
        raise HoldError(f"hold_rate: {hold_rate!r} must be a number >= 0 (inf = the model alone)")
    c = np.asarray(compensation, dtype=float)
    if math.isinf(hold_rate):
        return c.copy()
    t = np.asarray(time_s, dtype=float)
    out = np.full(t.size, np.nan)
    measured = [int(r) for r in measured_rows]
    if not measured or measured[0] >= start:
        raise HoldError(f"measured_rows: {measured[:3]!r}... must start with a row before {start}")
    bounds = [r for r in measured[1:] if start <= r < stop] + [stop - 1]
    lo = start
    for p, hi in zip(measured, bounds):
        rows = np.arange(lo, hi + 1)
        qdt = hold_rate * (t[rows] - t[p]) / 3600.0
        s2 = np.asarray(gp_std, dtype=float)[rows] ** 2
        w = np.where(qdt + s2 > 0, qdt / np.where(qdt + s2 > 0, qdt + s2, 1.0), 1.0)
        out[rows] = y[p] + w * (c[rows] - y[p])
        lo = hi + 1
    return out


def measured_hold_rate(time_s: np.ndarray, y: np.ndarray, n_calibration: int, lag_s: float = HOLD_RATE_LAG_S) -> float:
    """The displacement's random-walk rate (um^2/h) on rows < ``n_calibration``: the mean squared
    change over ``lag_s``, divided by ``lag_s``. It is the variance a held measurement gains per
    hour, measured, not tuned (FL_THERMAL training rows, 10 min: 8 / 7 / 35 / 32 / 16 um^2/h)."""
    t = np.asarray(time_s, dtype=float)[:n_calibration]
    v = np.asarray(y, dtype=float)[:n_calibration]
    if t.size < 3:
        raise HoldError(f"n_calibration: {n_calibration} rows cannot give a hold rate")
    lag = max(1, int(round(lag_s / float(np.median(np.diff(t))))))
    if lag >= t.size:
        raise HoldError(f"lag_s: {lag_s!r} s is longer than the {t.size} calibration rows")
    d = v[lag:] - v[:-lag]
    d = d[np.isfinite(d)]
    if d.size == 0:
        raise HoldError("y: no finite displacement change on the calibration rows")
    return float(np.mean(d * d) / (float(np.median(t[lag:] - t[:-lag])) / 3600.0))


def change_gain(measured, predicted, default: float = 0.0) -> float:
    """The share of a model's predicted changes that the measured changes make: the least-squares
    gain sum(dy dp) / sum(dp^2) over the finite pairs, clipped to [0, 1] (0 where the predicted
    changes do not happen: hold the last measurement); ``default`` without any predicted change."""
    dy, dp = np.asarray(measured, dtype=float), np.asarray(predicted, dtype=float)
    ok = np.isfinite(dy) & np.isfinite(dp)
    den = float(np.sum(dp[ok] ** 2))
    return float(np.clip(np.sum(dy[ok] * dp[ok]) / den, 0.0, 1.0)) if den > 0 else float(default)
