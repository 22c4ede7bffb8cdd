"""The change-probing threshold derived from the prior's own virtual experiment, not tuned on a run.

On a training programme of the prior (simulation: the error is known everywhere, no run that is
evaluated) each component's prior model runs between probings at the regular interval, its state
reset to the truth at each probing. Two figures come out per component: ``share``, the RMS error
of the model's predicted change since the last probing per unit of that change
(sqrt(sum e^2 / sum dp^2)), and ``hold_p99``, the P99 of the change itself (what holding the
probing loses at that interval). The goal is on P99_lin / P99_ang, each the mean of its
components' P99 (metrics.p99_group), so the level is one per group: ``goal`` x the group's mean
hold_p99 (the project's goal: half of probe-and-hold). A probing is worth spending when the error
the model expects from its predicted change, share x |dp|, reaches that level: the threshold on
|dp| is level / share, in multiples of the component's probe noise for
:func:`talc_model.probing.change_probing.change_probe_due`. Where the level is below the P99 of the probe
noise itself (2.576 sigma; the angular components at Table 5.4's 1.2 um/m) one probing cannot
bring the error there: no threshold (inf), those components never spend a probing.
docs/talc.md, "The probing threshold from the prior's own virtual experiment". No rclpy here.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from talc_model.arx.model import ArxModel

#: the project's goal: the model's P99 at most this share of probe-and-hold's
GOAL_SHARE = 0.5
#: P99 of |N(0, 1)|: a probing's own error at its 99th percentile, in probe-noise sigmas
NOISE_P99_SIGMAS = 2.576


class ChangeThresholdError(ValueError):
    """Bad input to the threshold derivation; the message names the argument and value."""


def between_probe_changes(model: ArxModel, u: np.ndarray, y: np.ndarray, interval: int
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(predicted change dp, true change dy) since the last probing, at every grid sample between
    probings every ``interval`` samples (the model's state reset to the truth ``y`` at each)."""
    if isinstance(interval, bool) or not isinstance(interval, (int, np.integer)) or interval < 1:
        raise ChangeThresholdError(f"interval: {interval!r} must be an integer >= 1 (grid samples)")
    y = np.asarray(y, float)
    lag = max(model.orders.max_lag, 1)
    if y.size < lag + 2 * interval:
        raise ChangeThresholdError(f"y: {y.size} grid samples are too few for probings every {interval}")
    measured = np.zeros(y.size, bool)
    measured[lag - 1::interval] = True
    pred = model.simulate(np.asarray(u, float), y[:lag], lag, measured, y)
    last = np.maximum.accumulate(np.where(measured, np.arange(y.size), -1))
    k = np.arange(lag, y.size)
    k = k[(last[k] >= 0) & ~measured[k]]
    p = last[k]
    dp, dy = pred[k] - y[p], y[k] - y[p]
    ok = np.isfinite(dp) & np.isfinite(dy)
    return dp[ok], dy[ok]


def change_figures(dp: np.ndarray, dy: np.ndarray) -> dict[str, float]:
    """``share`` and ``hold_p99`` of one component's between-probe changes (module docstring)."""
    dp, dy = np.asarray(dp, float), np.asarray(dy, float)
    if dp.shape != dy.shape or dp.size == 0:
        raise ChangeThresholdError(f"dp, dy: shapes {dp.shape} and {dy.shape} must be equal and non-empty")
    den = float(np.sum(dp ** 2))
    share = float(np.sqrt(np.sum((dy - dp) ** 2) / den)) if den > 0 else math.inf
    return {"share": share, "hold_p99": float(np.percentile(np.abs(dy), 99))}


def prior_change_thresholds(models: Mapping[str, ArxModel], u, errors, interval: int, noise: Mapping[str, float],
                            groups: Mapping[str, str], goal: float = GOAL_SHARE) -> dict[str, dict[str, float]]:
    """Per component of ``groups`` (name -> group, e.g. "linear" / "angular"): its figures on one
    training grid (``u``, the true ``errors`` per component; or lists of grids and errors, pooled),
    probings every ``interval`` grid samples, the group's level and the threshold in multiples of
    its probe noise (``inf``: no predicted change)."""
    us, errs = (list(u), list(errors)) if isinstance(u, (list, tuple)) else ([u], [errors])
    if not (isinstance(goal, (int, float)) and 0 < goal <= 1):
        raise ChangeThresholdError(f"goal: {goal!r} must be in (0, 1]")
    out = {}
    for c in groups:
        if c not in models or any(c not in e for e in errs) or c not in noise:
            raise ChangeThresholdError(f"groups: component {c!r} lacks a model, a training error or a probe noise")
        if not (math.isfinite(float(noise[c])) and float(noise[c]) > 0):
            raise ChangeThresholdError(f"noise[{c!r}]: {noise[c]!r} must be a finite number > 0")
        pairs = [between_probe_changes(models[c], ui, e[c], interval) for ui, e in zip(us, errs)]
        out[c] = change_figures(np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs]))
    for g in set(groups.values()):
        members = [c for c in groups if groups[c] == g]
        level = goal * float(np.mean([out[c]["hold_p99"] for c in members]))
        for c in members:
            resolvable = level > NOISE_P99_SIGMAS * float(noise[c])
            share = out[c]["share"]      # 0: the model predicts exactly; inf: it predicts no change
            limit = level / share if 0 < share < math.inf and resolvable else math.inf
            out[c].update(level=level, threshold_um=limit, threshold=limit / float(noise[c]))
    return out
