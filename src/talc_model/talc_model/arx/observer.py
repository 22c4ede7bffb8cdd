"""Observer-style state update of an ARX model from sparse, noisy probes (a Kalman filter on
the output history), stable for any autoregressive order.

The state of a MISO ARX model (``talc_model.arx.model``) between probes is its last n_a outputs
x = [E[k], E[k-1], .., E[k-n_a+1]] (the input lags are known). The thesis's TALC replaces only
E[k] by a probe (§6.2.2): for n_a > 1 that leaves an inconsistent history whose jump the other
poles amplify, and with a probe every 24 samples the switched system can diverge (a
refitted n_a = 4 model in the fault harness does; docs/talc.md). Here a probe
corrects the WHOLE state by the Kalman gain of the model's own dynamics:

    between probes  P <- F P F' + q e1 e1'          (F: companion matrix of A(q); the ARX
                                                     equation error enters at E[k])
    at a probe      K = P e1 / (P[0, 0] + r),  x <- x + K (measured - x[0]),  P <- P - K e1' P

``r`` is the probe's noise variance (Table 5.4); ``q`` is matched to the innovations the model
has actually seen (covariance matching: the prior variance P[0, 0] + r equals the mean square
of the recent innovations), so a model that predicts its probes well is trusted and one that
does not is corrected. For n_a = 1 this is a scalar gain in [K_MIN, 1); with slow poles the
gain vector is nearly constant, i.e. a probe shifts the recent history as a whole instead of
bending it. For a stable F the filter's error dynamics are stable (a Kalman filter of a stable,
observable model), whatever n_a. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: smallest gain on the newest output: the innovation window is short (TALC's
#: ``uncertainty_window``, 10 probes), so its variance estimate is noisy; a model is never
#: trusted more than 4 times a probe (prior variance >= r / 4, gain >= 0.2)
K_MIN = 0.2


class ObserverError(ValueError):
    """Bad input to the ARX observer; the message names the argument and value."""


@dataclass(frozen=True)
class ObserverScoring:
    """Score candidate models with the observer predictor (:func:`observer_predictions`):
    the probe's noise variance and TALC's innovation window."""

    noise_var: float
    window: int


def companion(a: np.ndarray) -> np.ndarray:
    """State transition of E[k] + a1 E[k-1] + .. = ... on x = [E[k], .., E[k-n_a+1]]."""
    a = np.asarray(a, float)
    na = a.size
    f = np.zeros((na, na))
    f[0, :] = -a
    if na > 1:
        f[1:, :-1] = np.eye(na - 1)
    return f


def propagate(a: np.ndarray, p_post: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """``steps`` prediction steps from the covariance ``p_post``: (F^s P F^s', sum_i F^i e1 e1' F^i')
    (the second is the covariance added by a unit-variance equation error per step)."""
    f = companion(a)
    na = f.shape[0]
    free = np.array(p_post, float).reshape(na, na)
    acc = np.zeros((na, na))
    e1 = np.zeros((na, na))
    if na:
        e1[0, 0] = 1.0
    for _ in range(max(0, int(steps))):
        free = f @ free @ f.T
        acc = f @ acc @ f.T + e1
    return free, acc


def observer_update(a: np.ndarray, p_post: np.ndarray, steps: int, innovation: float,
                    innovation_ms: float, noise_var: float, gain_scale: float = 1.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Correction of the state (add it to [E[k], E[k-1], ..]) and the new posterior covariance.

    ``p_post``: covariance after the previous probe, ``steps`` grid samples ago; ``innovation``:
    measured minus predicted E[k]; ``innovation_ms``: the mean square of recent innovations
    (what the prior variance plus the probe noise should add up to); ``noise_var``: the probe's
    noise variance; ``gain_scale`` in (0, 1] shrinks the gain (a fixed-gain damping on top).
    """
    a = np.asarray(a, float)
    na = a.size
    for name, v in (("innovation", innovation), ("innovation_ms", innovation_ms), ("noise_var", noise_var)):
        if not math.isfinite(v):
            raise ObserverError(f"observer: {name} {v!r} is not finite")
    if noise_var < 0 or innovation_ms < 0:
        raise ObserverError(f"observer: noise_var {noise_var!r} and innovation_ms {innovation_ms!r} must be >= 0")
    if not 0 < gain_scale <= 1:
        raise ObserverError(f"observer: gain_scale {gain_scale!r} must be in (0, 1]")
    if na == 0:  # an FIR model has no output state: nothing to correct
        return np.zeros(0), np.zeros((0, 0))
    free, acc = propagate(a, p_post, steps)
    if acc[0, 0] > 0:
        q = max(0.0, (innovation_ms - noise_var - free[0, 0]) / acc[0, 0])
    else:  # a second probe on the same sample: no time for the error to grow
        q = 0.0
    prior = free + q * acc
    floor = noise_var * K_MIN / (1.0 - K_MIN)
    if prior[0, 0] < floor:
        # too little prior variance: add it along the direction of the equation error (or the
        # newest output alone if no step has passed) so the gain on E[k] is K_MIN
        shape = acc if acc[0, 0] > 0 else np.eye(na)[:, :1] @ np.eye(na)[:1, :]
        prior = prior + (floor - prior[0, 0]) / shape[0, 0] * shape
    s = prior[0, 0] + noise_var
    if s <= 0:  # no noise, no uncertainty: the model is exact
        return np.zeros(na), prior
    k = gain_scale * prior[:, 0] / s
    i_kh = np.eye(na)
    i_kh[:, 0] -= k
    post = i_kh @ prior @ i_kh.T + noise_var * np.outer(k, k)   # Joseph form: any gain_scale
    post = 0.5 * (post + post.T)
    return k * innovation, post


def observer_predictions(model, u: np.ndarray, y: np.ndarray, start: int, measured: np.ndarray,
                         noise_var: float, window: int, gain_scale: float = 1.0,
                         p_start: np.ndarray | None = None) -> np.ndarray:
    """TALC's predictor with the observer state update, offline: predictions for k = start ..
    N-1 of ``model`` (a :class:`talc_model.arx.model.ArxModel`) fed back on their own between the
    ``measured`` samples; at a measured sample its prediction is recorded, then the state is
    corrected by :func:`observer_update` (innovation window of ``window`` probes, covariance
    matching as in ``TalcModel._observe``). ``y[:start]`` is the initial history, known to the
    probe noise (as after TALC's first fit). NaN before ``start``. The same predictor the
    online loop runs, so candidate models are ranked by what the loop will do with them."""
    if window < 1:
        raise ObserverError(f"observer_predictions: window {window!r} must be >= 1")
    x, bu = model.simulation_start(u, y, start, "observer_predictions")
    n = len(bu)
    pred = np.full(n, np.nan)
    na = model.orders.na
    meas = np.asarray(measured, bool)
    meas_idx = [int(k) for k in np.flatnonzero(meas[start:]) + start if math.isfinite(y[k])]
    k_last = start - 1
    p = noise_var * np.eye(na) if p_start is None else np.array(p_start, float).reshape(na, na)
    recent: list[float] = []
    probes = set(meas_idx)
    s0 = start
    for s1 in meas_idx + ([n - 1] if not meas_idx or meas_idx[-1] != n - 1 else []):
        if s1 < s0:
            continue
        pred[s0:s1 + 1] = x[s0:s1 + 1] = model.free_run(bu, x, s0, s1 + 1)
        s0 = s1 + 1
        if s1 not in probes or not math.isfinite(pred[s1]) or na == 0:
            continue
        innovation = float(y[s1] - pred[s1])
        ms = float(np.mean(np.square(recent[-(window - 1):] + [innovation]))) if window > 1 else innovation ** 2
        corr, p = observer_update(model.a, p, s1 - k_last, innovation, ms, noise_var, gain_scale)
        lo = max(0, s1 - na + 1)
        x[lo:s1 + 1] += corr[: s1 + 1 - lo][::-1]
        k_last = s1
        recent = (recent + [innovation])[-window:]
    return pred
