"""Adaptive mode of ``thermal-comp evaluate``: any open-loop model plus probes at the user's budget.

After the training rows (the calibration phase) a probing measures every displacement channel
(one 95-s cycle, charged in Q_prod):

- **scheduled**: every ``probe_every_h`` hours after the end of the previous cycle;
- **the model's own**: when the model predicts a change of more than ``tolerance_um`` on any
  channel since the last probing (it sees a load change the held probe cannot), at the
  earliest ``min_gap_s`` after the previous cycle, and only while the probings after
  calibration stay within ``max_probes_per_h`` x elapsed hours: the budget is a hard cap;
- with ``load_delay_min`` (``--load-probing``): also D minutes after a machine-input step, all
  probings then drawn from a token bucket (:mod:`talc_model.open_loop.load_probing`) instead of the cap.

Between probings the compensation is the **uncertainty-weighted hold**
(:func:`talc_model.probing.uncertainty_weighted_hold`): the held probe y_p moved towards the model
corrected by its residual at that probe, c = p + (y_p - p(t_p)), by the weight w. The error of
y_p + w (c - y_p) is dy - w dp (dy the displacement's change since the probe, dp the model's), so
the best w is the share of the model's predicted change that the displacement makes,
sum(dy dp) / sum(dp^2) in [0, 1]: *measured* on the training rows (the model's out-of-fold
walk-forward prediction, over the probing interval) and then from the model's own probings (the
last few pairs of consecutive probings, :func:`online_gains`). A model whose predicted changes do
not happen (noise, a plateau it does not see) gets w near 0 and the held probe wins: the result
is never clearly worse than holding. (The rates q of a held probe and of the model error are
reported beside it.)
The baseline beside each model holds that model's own probes at exactly its probe instants.
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from talc_model.probing.uncertainty_weighted_hold import change_gain, measured_hold_rate, uncertainty_weighted_hold
from talc_model.open_loop.load_probing import bucket_schedule, input_steps
from talc_model.open_loop.probe_gain_update import regained_compensation
from talc_model.open_loop.probe_refit import RidgeRefit
from thermal_comp_common.metrics import q_prod
from thermal_eval.evaluate.spec import EvaluationData

PROBE_DURATION_S = 95.0
#: pairs of consecutive probings whose changes set the gain
GAIN_MEMORY = 4


class AdaptiveSettingsError(ValueError):
    """A bad probing setting; the message names it."""


@dataclass(frozen=True)
class ProbingBudget:
    probe_every_h: float = 2.0            # the user's schedule
    max_probes_per_h: float = 1.0         # hard cap on all probings after calibration (average)
    tolerance_um: float = 1.0             # predicted change that asks for a probing
    min_gap_s: float = 600.0              # after the end of the previous cycle
    probe_duration_s: float = PROBE_DURATION_S
    probe_resolution_um: float = 0.0      # the user's probe: a predicted change below it is not acted on
    phase_h: float = 0.0                  # the probing clock starts this long after calibration ends
    #: the load-change rule (:mod:`talc_model.open_loop.load_probing`): a probing due this long after a
    #: machine-input step, all probings from a token bucket of this depth; None: off (the cap above)
    load_delay_min: float | None = None
    bucket_depth: float = 1.0
    bucket_credit: float = 1.0            # probings the bucket holds when the clock starts (0 or 1)

    def __post_init__(self) -> None:
        for k in ("probe_every_h", "max_probes_per_h", "tolerance_um", "min_gap_s", "probe_duration_s"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise AdaptiveSettingsError(f"{k}: {v!r} must be a finite number > 0")
        for k in ("probe_resolution_um", "phase_h"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise AdaptiveSettingsError(f"{k}: {v!r} must be a finite number >= 0")
        d = self.load_delay_min
        if d is not None and not (isinstance(d, (int, float)) and math.isfinite(d) and d >= 0):
            raise AdaptiveSettingsError(f"load_delay_min: {d!r} must be None or a finite number >= 0")
        b = self.bucket_depth
        if not (isinstance(b, (int, float)) and math.isfinite(b) and b >= 1):
            raise AdaptiveSettingsError(f"bucket_depth: {b!r} must be a finite number >= 1")
        c = self.bucket_credit
        if not (isinstance(c, (int, float)) and math.isfinite(c) and 0 <= c <= 1):
            raise AdaptiveSettingsError(f"bucket_credit: {c!r} must be a number in [0, 1]")

    @property
    def interval_h(self) -> float:
        """The probing interval the budget allows: the schedule's or the cap's, the shorter."""
        return min(self.probe_every_h, 1.0 / self.max_probes_per_h)


def phase_budgets(budget: ProbingBudget, k: int) -> list[ProbingBudget]:
    """The budget with its probing clock delayed by i/k of the probing interval, i = 0..k-1
    (phase 0 is ``budget`` itself): the same schedule and cap at k phases, to score a model
    over where its probings happen to fall rather than at one phase's luck."""
    if not (isinstance(k, int) and k >= 1):
        raise AdaptiveSettingsError(f"probe_phases: {k!r} must be an integer >= 1")
    return [budget] + [replace(budget, phase_h=budget.phase_h + i * budget.interval_h / k) for i in range(1, k)]


@dataclass
class AdaptiveResult:
    compensation: dict[str, np.ndarray]      # blended, rows >= n_train
    corrected: dict[str, np.ndarray]         # model + last residual, no blend
    hold: dict[str, np.ndarray]              # holding the same probes
    probe_rows: list[int]
    triggered_rows: list[int]
    weights: dict[str, float]                # w = q_y / (q_y + q_m) per channel
    rates: dict[str, dict[str, float]] = field(default_factory=dict)
    load_rows: list[int] = field(default_factory=list)   # probings due after a machine-input step


def probe_schedule(data: EvaluationData, prediction: Mapping[str, np.ndarray], budget: ProbingBudget) -> tuple[list[int], list[int]]:
    """Probe rows after calibration (and which of them the model asked for); uses only the
    time, the model's prediction, the machine inputs and the count of probings so far (never a
    displacement). ``budget.phase_h`` delays the probing clock (schedule and cap): no probing
    before it. With ``budget.load_delay_min`` the load-change rule and its token bucket decide
    (:func:`talc_model.open_loop.load_probing.bucket_schedule`) instead of the cumulative cap."""
    rows, asked, _ = _schedule(data, prediction, budget)
    return rows, asked


def _asks(prediction: Mapping[str, np.ndarray], tolerance_um: float):
    """The model's own rule: it asks for a probing when its prediction of some channel moved by
    more than ``tolerance_um`` since the last probing (row ``last``)."""
    return lambda r, last: any(abs(prediction[c][r] - prediction[c][last]) > tolerance_um for c in prediction)


def _schedule(data: EvaluationData, prediction: Mapping[str, np.ndarray], budget: ProbingBudget
              ) -> tuple[list[int], list[int], list[int]]:
    """:func:`probe_schedule` and the probings due after a machine-input step."""
    t = data.time_s
    start = data.split.n_train
    clock0 = t[start - 1] + 3600.0 * budget.phase_h
    model_asks = _asks(prediction, budget.tolerance_um)
    if budget.load_delay_min is not None:
        return bucket_schedule(t, start, clock0, input_steps(data.inputs, start), budget.max_probes_per_h,
                               budget.bucket_depth, 60.0 * budget.load_delay_min, budget.min_gap_s,
                               3600.0 * budget.probe_every_h, budget.probe_duration_s,
                               model_asks, budget.bucket_credit)
    last_end = clock0                            # the calibration phase ends with a measurement
    last_row = start - 1
    rows, triggered = [], []
    for r in range(start, len(data)):
        since = t[r] - last_end
        if since < 0:
            continue
        elapsed_h = (t[r] - clock0) / 3600.0
        scheduled = since >= budget.probe_every_h * 3600.0
        asks = since >= budget.min_gap_s and model_asks(r, last_row)
        within = len(rows) + 1 <= budget.max_probes_per_h * elapsed_h
        if scheduled or (asks and within):
            rows.append(r)
            if not scheduled:
                triggered.append(r)
            last_end, last_row = t[r] + budget.probe_duration_s, r
    return rows, triggered, []


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


#: a predicted change counts once it exceeds the noise of the difference of two readings at
#: two standard deviations: 2 sqrt(2) sigma
DEAD_BAND_SIGMAS = 2.0 * math.sqrt(2.0)


def within_runs(run_id: np.ndarray | None, stop: int, lag: int, first: int = 0) -> np.ndarray:
    """For the pairs (i, i + lag), first <= i < stop - lag: both rows readings of one run (no
    jump from one run's end to the next one's start, no made-up rest row); all of them for one
    recording (``run_id`` None)."""
    m = max(0, stop - lag - first)
    if run_id is None:
        return np.ones(m, bool)
    a, b = run_id[first:first + m], run_id[first + lag:first + lag + m]
    return (a == b) & (a >= 0)


def _changes(y: np.ndarray, n_train: int, run_id: np.ndarray | None) -> np.ndarray:
    """Row-to-row changes of the training rows inside one run."""
    d = np.diff(np.asarray(y[:n_train], dtype=float))
    return d[within_runs(run_id, n_train, 1)] if d.size else d


def reading_noise_um(y: np.ndarray, n_train: int, run_id: np.ndarray | None = None) -> float:
    """The noise of one displacement reading, measured on the training rows: the robust spread
    (1.4826 MAD) of the row-to-row changes around their median, over sqrt(2) (a change is the
    difference of two readings; only inside one run: :func:`within_runs`). Slow drift moves the
    median, not the spread."""
    d = _changes(y, n_train, run_id)
    d = d[np.isfinite(d)]
    if d.size < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


#: share of the row-to-row changes that must lie on one grid for a signal to count as quantised
ON_GRID_SHARE = 0.95


def resolution_um(y: np.ndarray, n_train: int, run_id: np.ndarray | None = None) -> float:
    """The step of a quantised displacement, measured on the training rows (0: not quantised):
    the smallest non-zero change between two readings, when at least :data:`ON_GRID_SHARE` of
    the non-zero changes are whole multiples of it (within 5 % of a step). On such a signal
    most changes are 0 and the noise measured from them is 0, so the step is the dead band."""
    d = np.abs(_changes(y, n_train, run_id))
    d = d[np.isfinite(d)]
    scale = float(np.max(d)) if d.size else 0.0
    nz = d[d > 1e-9 * max(scale, 1e-12)]
    if nz.size < 10:
        return 0.0
    q = float(np.min(nz))
    k = nz / q
    return q if float(np.mean(np.abs(k - np.round(k)) <= 0.05)) >= ON_GRID_SHARE else 0.0


def dead_band_um(y: np.ndarray, n_train: int, probe_resolution_um: float = 0.0,
                 run_id: np.ndarray | None = None, prediction: np.ndarray | None = None) -> float:
    """Predicted changes smaller than this are not acted on (the compensation holds): the largest
    of the probe's resolution, the step of a quantised signal (:func:`resolution_um`), two
    standard deviations of the difference of two readings (a smaller change cannot be told from
    the probes' noise, so the probes cannot confirm it: on a plateau those are the wrong ones) and,
    with ``prediction``, two standard deviations of the difference of two values of the model's
    prediction (its own noise, from its inputs')."""
    noises = [y] + ([prediction] if prediction is not None else [])
    return max([float(probe_resolution_um), resolution_um(y, n_train, run_id)]
               + [DEAD_BAND_SIGMAS * reading_noise_um(v, n_train, run_id) for v in noises])


def shrink(dp: np.ndarray, band: float) -> np.ndarray:
    """The predicted change acted on: 0 inside the dead band, dp (1 - band^2 / dp^2) beyond it
    (the non-negative garrote: continuous at the band like a soft threshold, but a change well
    beyond it is followed almost whole; a soft threshold cut every change by the whole band)."""
    dp = np.asarray(dp, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        kept = np.where(np.abs(dp) > band, dp * (1.0 - band ** 2 / np.where(dp != 0, dp ** 2, 1.0)), 0.0)
    return np.where(np.isnan(dp), np.nan, kept)


def training_gain(t: np.ndarray, y: np.ndarray, p_oof: np.ndarray, first: int, stop: int, lag_h: float,
                  band: float = 0.0, run_id: np.ndarray | None = None) -> float:
    """The share of the model's predicted change over ``lag_h`` that the displacement made on the
    training rows (out-of-fold prediction): sum(dy dp) / sum(dp^2), clipped to [0, 1]; over pairs
    of readings of one run (:func:`within_runs`: a run's jump back to its own start reference and
    its made-up rest are not changes the model was asked to predict)."""
    step = float(np.median(np.diff(t[first:stop])))
    lag = max(1, int(round(lag_h * 3600.0 / step)))
    if stop - first <= lag:
        return 0.0
    ok = within_runs(run_id, stop, lag, first)
    dy = (y[first + lag:stop] - y[first:stop - lag])[ok]
    dp = shrink(p_oof[first + lag:stop] - p_oof[first:stop - lag], band)[ok]
    return change_gain(dy, dp)


def online_gains(y: np.ndarray, p: np.ndarray, measured: list[int], gain0: float,
                 memory: int = GAIN_MEMORY, band: float = 0.0) -> np.ndarray:
    """The gain in force after each measurement: the training gain until two probings have been
    made, then sum(dy dp) / sum(dp^2) over the last ``memory`` pairs of consecutive probings
    (dy measured, dp the model's change between them), clipped to [0, 1]. Reads the
    displacement at measured rows only."""
    gains = [gain0]
    dys: list[float] = []
    dps: list[float] = []
    for prev, r in zip(measured[:-1], measured[1:]):
        dys.append(float(y[r] - y[prev]))
        dps.append(float(shrink(np.asarray(p[r] - p[prev]), band)))
        if len(dys) < 2:
            gains.append(gain0)
            continue
        gains.append(change_gain(dys[-memory:], dps[-memory:], default=gain0))
    return np.asarray(gains)


def _segment_values(values: np.ndarray, measured: list[int], start: int, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    bounds = measured[1:] + [n - 1]
    lo = start
    for v, hi in zip(values, bounds):
        out[lo:hi + 1] = v
        lo = hi + 1
    return out


def run_adaptive(data: EvaluationData, prediction: Mapping[str, np.ndarray], oof: Mapping[str, tuple[np.ndarray, int]],
                 budget: ProbingBudget, regain: Mapping[str, tuple[np.ndarray, float]] | None = None) -> AdaptiveResult:
    """One model in adaptive mode: schedule, rates from the training rows (updated at each of
    its probings), blended compensation. ``regain``: per channel the model's per-input
    contributions and the walk-forward's penalty (and forgetting); there the probes re-estimate the gains
    (:mod:`talc_model.open_loop.probe_gain_update`) and that replaces the blend (w = 1, dead band kept)."""
    n, start, t = len(data), data.split.n_train, data.time_s
    rows, triggered, load = _schedule(data, prediction, budget)
    measured = [start - 1] + rows
    since_h = np.nan_to_num(_since_probe_h(t, measured, start, n))
    comp, corr, hold, weights, rates = {}, {}, {}, {}, {}
    lag_h = budget.interval_h
    for c, p in prediction.items():
        y = data.displacement_um[c]
        p_oof, first = oof[c]
        band = dead_band_um(y, start, budget.probe_resolution_um, data.run_id, p)
        q_y = measured_hold_rate(t, y, start)
        q_m = measured_hold_rate(t[first:start], (y - p_oof)[first:start], start - first)
        gain0 = training_gain(t, y, p_oof, first, start, lag_h, band, data.run_id)
        gains = online_gains(y, p, measured, gain0, band=band)
        if regain and c in regain and isinstance(regain[c], RidgeRefit):    # re-fitted at each probing
            corrected = regain[c].compensation(y, measured, start, n)
            gains = np.ones_like(gains)
        elif regain and c in regain:
            contrib, penalty, *forgetting = regain[c]        # (contributions, penalty[, forgetting])
            corrected = regained_compensation(y, p, contrib, measured, start, n, penalty, *forgetting)
            gains = np.ones_like(gains)
        else:
            corrected = _piecewise_offset(y, p, measured, start, n)
        y_p = _segment_values(y[measured], measured, start, n)
        outside = y_p + shrink(corrected - y_p, band)          # the model's change beyond the dead band
        # uncertainty-weighted hold with a unit hold rate: w = dt / (dt + s^2) = gain
        g = _segment_values(gains, measured, start, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s2 = np.where(g > 0, since_h * (1.0 - g) / np.where(g > 0, g, 1.0), np.inf)
        comp[c] = uncertainty_weighted_hold(t, y, np.nan_to_num(outside), np.sqrt(s2), measured, start, n, 1.0)
        hold[c] = y_p          # the last probe before each row (a probe row was compensated before its probe)
        corr[c] = corrected
        weights[c] = float(np.mean(gains))
        rates[c] = {"hold_rate_um2_per_h": round(q_y, 3), "model_error_rate_um2_per_h": round(q_m, 3),
                    "training_gain": round(gain0, 3), "dead_band_um": round(band, 4),
                    "quantised_step_um": round(resolution_um(y, start, data.run_id), 4)}
    return AdaptiveResult(comp, corr, hold, rows, triggered, weights, rates, load)


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
