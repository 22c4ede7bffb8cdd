"""What the greedy search adopted, refitted together and pruned on held-out data.

The search adopts one effect per round, each fitted on top of the ones before it with their
values fixed: with two effects concealed, the first is fitted while the second is still
missing, and its values carry the second's share (a conductance 12 % high, a channel it
does not act on made worse). After the search:

1. **Joint refit** (:func:`refit`): every adopted effect's parameters together, on the
   training window, from the values the rounds found (same bounds).
2. **Each pays for itself** (:func:`prune`): an adopted effect stays only if removing it
   from the refitted set makes the held-out weighted sum of squares of the channels it acts
   on rise by at least ``min_improvement_pct`` (extra adoptions must earn their place on
   data no fit has seen).
3. **Never worse** (:func:`prune`): the kept set must leave no channel measurably worse on
   held-out data than the search's start (:func:`thermal_twin.diagnose.fit.worse_channels`);
   otherwise the last adopted effect is dropped, and so on.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import least_squares

from thermal_twin.diagnose.fit import FitProblem, Hypothesis, acted_improvement_pct, worse_channels
from thermal_twin.machine.schema import MachineSpecError


def _spec(base: dict, hyps: list[Hypothesis], values: list[np.ndarray]) -> dict:
    spec = base
    for h, v in zip(hyps, values):
        spec = h.candidate.apply(spec, v)
    return spec


def _split(hyps: list[Hypothesis], x: np.ndarray) -> list[np.ndarray]:
    out, k = [], 0
    for h in hyps:
        n = len(h.candidate.params)
        out.append(np.asarray(x[k:k + n], dtype=float))
        k += n
    return out


def refit(problem: FitProblem, base: dict, hyps: list[Hypothesis], max_nfev: int = 40) -> list[np.ndarray]:
    """The adopted effects' values fitted together on the training window (from their round
    values); the round values again if the joint fit fails or does not lower the cost."""
    x0 = np.concatenate([np.asarray(h.values, dtype=float) for h in hyps])
    lo = np.concatenate([[p.lo for p in h.candidate.params] for h in hyps])
    hi = np.concatenate([[p.hi for p in h.candidate.params] for h in hyps])
    x0 = np.clip(x0, lo, hi)
    scale = np.maximum(np.abs(x0), 1e-3 * (hi - lo))
    size = problem.train_residual(problem.outputs(base, stop=problem.n_train)).size

    def fun(x):
        try:
            y = problem.outputs(_spec(base, hyps, _split(hyps, x)), stop=problem.n_train)
            return problem.train_residual(y).ravel()
        except MachineSpecError:
            return np.full(size, 1e6)
    try:
        c0 = float(np.sum(fun(x0) ** 2))
        sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=scale, method="trf", max_nfev=max_nfev,
                            xtol=1e-6, ftol=1e-8)
    except (ValueError, MachineSpecError):
        return [np.asarray(h.values, dtype=float) for h in hyps]
    if not 2 * sol.cost < c0:
        return [np.asarray(h.values, dtype=float) for h in hyps]
    return _split(hyps, sol.x)


def _gain(problem: FitProblem, y_with: np.ndarray, y_without: np.ndarray) -> float:
    """Held-out gain of an effect, in %, on the channels it acts on."""
    nt = problem.n_train
    return acted_improvement_pct(problem.weighted_residual(y_without, nt), problem.weighted_residual(y_with, nt))


def prune(problem: FitProblem, base: dict, y_base: np.ndarray, hyps: list[Hypothesis],
          min_improvement_pct: float) -> tuple[list[Hypothesis], list[dict]]:
    """Refit the adopted effects together, drop those that do not pay for themselves on
    held-out data and then, last first, those that leave a channel worse; returns (kept
    hypotheses with their refitted values and descriptions, a record of each drop)."""
    if not hyps:
        return [], []
    values = refit(problem, base, hyps) if len(hyps) > 1 else [np.asarray(hyps[0].values, dtype=float)]
    kept, vals, dropped = list(hyps), list(values), []
    while len(kept) > 1:
        y_all = problem.outputs(_spec(base, kept, vals))
        gains = []
        for j in range(len(kept)):
            rest = [h for i, h in enumerate(kept) if i != j]
            rv = [v for i, v in enumerate(vals) if i != j]
            gains.append(_gain(problem, y_all, problem.outputs(_spec(base, rest, rv))))
        j = int(np.argmin(gains))
        if gains[j] >= min_improvement_pct:
            break
        dropped.append({"effect": kept[j].candidate.key, "reason": "does not pay for itself on held-out data",
                        "holdout_gain_pct": gains[j]})
        del kept[j], vals[j]
    while kept:
        worse = worse_channels(problem, y_base, problem.outputs(_spec(base, kept, vals)))
        if not worse:
            break
        dropped.append({"effect": kept[-1].candidate.key, "reason": "leaves a channel worse on held-out data",
                        "worse_channels": worse})
        del kept[-1], vals[-1]
    out = []
    for i, (h, v) in enumerate(zip(kept, vals)):
        out.append(dataclasses.replace(h, values=v, spec=_spec(base, kept[:i + 1], vals[:i + 1]),
                                       indistinguishable_from=list(h.indistinguishable_from),
                                       tell_apart=list(h.tell_apart)))
    return out, dropped
