"""Adaptive mode of ``thermal-comp evaluate``: any open-loop model plus probes at the user's budget.

After the training rows (the calibration phase) a probing measures every displacement channel
(one 95-s cycle, charged in Q_prod):

- **scheduled**: every ``probe_every_h`` hours after the end of the previous cycle;
- **the model's own**: when the model predicts a change of more than ``tolerance_um`` on any
  channel since the last probing (it sees a load change the held probe cannot), at the
  earliest ``min_gap_s`` after the previous cycle, and only while the probings after
  calibration stay within ``max_probes_per_h`` x elapsed hours (+1): the budget is a hard cap.

Between probings the compensation is the **uncertainty-weighted hold**
(:func:`talc_model.uncertainty_weighted_hold`): the model corrected by its residual at the last
probe, c = p + (y_p - p(t_p)), blended with the held probe y_p by their variances. Both grow
like random walks since the probe: the held probe with the displacement's rate q_y, the
corrected model with its error's rate q_m; both are *measured* on the training rows (q_m on the
model's out-of-fold walk-forward residuals), so a model whose error drifts faster than the
displacement itself is given little weight and the result is never clearly worse than holding.
The baseline beside each model holds that model's own probes at exactly its probe instants.
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from talc_model.uncertainty_weighted_hold import measured_hold_rate, uncertainty_weighted_hold
from thermal_comp_common.metrics import q_prod
from thermal_eval.evaluation_spec import EvaluationData

PROBE_DURATION_S = 95.0


class AdaptiveSettingsError(ValueError):
    """A bad probing setting; the message names it."""


@dataclass(frozen=True)
class ProbingBudget:
    probe_every_h: float = 2.0            # the user's schedule
    max_probes_per_h: float = 1.0         # hard cap on all probings after calibration (average)
    tolerance_um: float = 1.0             # predicted change that asks for a probing
    min_gap_s: float = 600.0              # after the end of the previous cycle
    probe_duration_s: float = PROBE_DURATION_S

    def __post_init__(self) -> None:
        for k in ("probe_every_h", "max_probes_per_h", "tolerance_um", "min_gap_s", "probe_duration_s"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise AdaptiveSettingsError(f"{k}: {v!r} must be a finite number > 0")


@dataclass
class AdaptiveResult:
    compensation: dict[str, np.ndarray]      # blended, rows >= n_train
    corrected: dict[str, np.ndarray]         # model + last residual, no blend
    hold: dict[str, np.ndarray]              # holding the same probes
    probe_rows: list[int]
    triggered_rows: list[int]
    weights: dict[str, float]                # w = q_y / (q_y + q_m) per channel
    rates: dict[str, dict[str, float]] = field(default_factory=dict)


def probe_schedule(data: EvaluationData, prediction: Mapping[str, np.ndarray], budget: ProbingBudget) -> tuple[list[int], list[int]]:
    """Probe rows after calibration (and which of them the model asked for); uses only the
    time, the model's prediction and the count of probings so far (never a displacement)."""
    t = data.time_s
    start = data.split.n_train
    last_end = t[start - 1]                      # the calibration phase ends with a measurement
    last_row = start - 1
    rows, triggered = [], []
    for r in range(start, len(data)):
        since = t[r] - last_end
        if since < 0:
            continue
        elapsed_h = (t[r] - t[start - 1]) / 3600.0
        scheduled = since >= budget.probe_every_h * 3600.0
        asks = since >= budget.min_gap_s and any(
            abs(prediction[c][r] - prediction[c][last_row]) > budget.tolerance_um for c in prediction)
        within = len(rows) + 1 <= budget.max_probes_per_h * elapsed_h + 1
        if scheduled or (asks and within):
            rows.append(r)
            if not scheduled:
                triggered.append(r)
            last_end, last_row = t[r] + budget.probe_duration_s, r
    return rows, triggered


def _piecewise_offset(y: np.ndarray, p: np.ndarray, measured: list[int], start: int, n: int) -> np.ndarray:
    """p + (y_p - p_p) with p the last measurement strictly before each row (rows >= start)."""
    out = np.full(n, np.nan)
    bounds = [r for r in measured[1:]] + [n - 1]
    lo = start
    for m, hi in zip(measured, bounds):
        out[lo:hi + 1] = p[lo:hi + 1] + (y[m] - p[m])
        lo = hi + 1
    return out


def _since_probe_h(t: np.ndarray, measured: list[int], start: int, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    bounds = measured[1:] + [n - 1]
    lo = start
    for m, hi in zip(measured, bounds):
        out[lo:hi + 1] = (t[lo:hi + 1] - t[m]) / 3600.0
        lo = hi + 1
    return out


def run_adaptive(data: EvaluationData, prediction: Mapping[str, np.ndarray], oof: Mapping[str, tuple[np.ndarray, int]],
                 budget: ProbingBudget) -> AdaptiveResult:
    """One model in adaptive mode: schedule, rates from the training rows, blended compensation."""
    n, start, t = len(data), data.split.n_train, data.time_s
    rows, triggered = probe_schedule(data, prediction, budget)
    measured = [start - 1] + rows
    since_h = _since_probe_h(t, measured, start, n)
    comp, corr, hold, weights, rates = {}, {}, {}, {}, {}
    for c, p in prediction.items():
        y = data.displacement_um[c]
        q_y = measured_hold_rate(t, y, start)
        p_oof, first = oof[c]
        q_m = measured_hold_rate(t[first:start], (y - p_oof)[first:start], start - first)
        corrected = _piecewise_offset(y, p, measured, start, n)
        std = np.sqrt(q_m * np.nan_to_num(since_h))
        comp[c] = uncertainty_weighted_hold(t, y, np.nan_to_num(corrected), std, measured, start, n, q_y)
        hold[c] = uncertainty_weighted_hold(t, y, np.nan_to_num(corrected), std, measured, start, n, 0.0)
        corr[c] = corrected
        weights[c] = q_y / (q_y + q_m) if q_y + q_m > 0 else 0.0
        rates[c] = {"hold_rate_um2_per_h": round(q_y, 3), "model_error_rate_um2_per_h": round(q_m, 3)}
    return AdaptiveResult(comp, corr, hold, rows, triggered, weights, rates)


def probe_counts(data: EvaluationData, rows: list[int], budget: ProbingBudget) -> dict:
    """Probings per window, per hour after calibration, and Q_prod after calibration."""
    s = data.split
    t = data.time_s
    after_h = (t[-1] - t[s.n_train - 1]) / 3600.0
    inside = lambda sl: sum(1 for r in rows if sl.start <= r < sl.stop)   # noqa: E731
    return {"probings_after_calibration": len(rows), "probings_test": inside(s.test),
            "probings_validation": inside(s.validation),
            "probings_per_h_after_calibration": round(len(rows) / after_h, 3) if after_h > 0 else math.nan,
            "q_prod_after_calibration_pct": round(q_prod(len(rows), after_h * 3600.0, budget.probe_duration_s), 2)}
