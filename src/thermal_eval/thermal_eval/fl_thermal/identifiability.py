"""Can the recording tell a mechanism from the finder's other words? From the calibrated twin alone.

A mechanism the recording supports may still not be *identifiable*: another
word of the vocabulary (a conduction path sharing an end, a gain on a nearly collinear node)
may reproduce what its removal does. The criterion (docs/diagnose.md, stated before the finder
ran on it) imagines the calibrated twin were the truth. Removing mechanism m leaves the
weighted residual d = y_calibrated - y_ablated. Every other candidate of the finder's library
(its words on the calibrated twin; m's own word left out) is linearised at its probes
(:func:`thermal_twin.diagnose.fit.probe_values`, the directions the screening projects on),
fitted to d on the training rows (one start at a time, as the screening does; the start's
direction with the sign the finder's bounds and plausibility checks allow) and scored on
the held-out rows by what it leaves of d. m is identifiable when its best competitor leaves at
least ``MIN_DISTINCT`` of the calibrated twin's own held-out weighted SSE: what tells m from
that competitor is then itself a "supported" amount (the 20 % of the support rule) beside the
misfit the real recording adds on top. Linearised at the calibrated twin, not at each ablated
one: one set of twin runs serves every mechanism.
"""
from __future__ import annotations

import copy

import numpy as np
from scipy.optimize import lsq_linear

from thermal_twin.machine.schema import MachineSpecError
from thermal_twin.diagnose.effects import candidates, classify_driver
from thermal_twin.diagnose.fit import FitProblem, linear_change, probe_values
from thermal_eval.fl_thermal.mechanisms import Mechanism

#: identifiable when the best competitor leaves at least this share of the calibrated twin's
#: held-out weighted SSE unexplained (the support rule's 20 %, fl_thermal_mechanisms.MIN_RATIO - 1)
MIN_DISTINCT = 0.2


def _split(problem: FitProblem, dw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(training rows every stride-th sample, held-out rows) of a weighted change, raveled."""
    nt = problem.n_train
    return dw[:, :nt:problem.stride].ravel(), dw[:, nt:].ravel()


def competitor_directions(problem: FitProblem, spec_c: dict, y_c: np.ndarray) -> list[dict]:
    """Every candidate of the finder's library on ``spec_c``: its key and the weighted output
    changes of its probes (train, held-out), one group per start value with the steps of its
    further parameters."""
    drivers = {n: classify_driver(n, v) for n, v in problem.recording.inputs.items()}
    r_c = problem.weighted_residual(y_c)
    cache: dict = {}
    out = []
    for c in candidates(spec_c, drivers, problem.channels):
        if c.effect == "none":
            continue
        starts, probes = probe_values(c)
        cols = []
        try:
            for v in probes:
                dy = linear_change(problem, spec_c, c, v, y_c, cache)
                y = y_c + dy if dy is not None else problem.outputs(c.apply(spec_c, v))
                cols.append(_split(problem, r_c - problem.weighted_residual(y)))
        except MachineSpecError:
            continue
        ns = len(starts)
        out.append({"key": f"{c.effect}:{c.target}", "starts": cols[:ns], "steps": cols[ns:],
                    "negative": [_negative_ok(c, v) for v in starts]})
    return out


def _negative_ok(c, v: np.ndarray) -> bool:
    """Whether the finder could fit the candidate's change at start ``v`` with the opposite
    sign: the negated first parameter is within its fitting bounds and passes the effect's
    plausibility check (a lag cannot be negated, nor a new conduction path or a heat source
    made negative; a gain or a bias can)."""
    w = np.array(v, dtype=float)
    w[0] = -w[0]
    p = c.params[0]
    return bool(p.lo <= w[0] <= p.hi and c.implausible(w) is None)


def _left(d_tr: np.ndarray, d_h: np.ndarray, comp: dict) -> float:
    """What competitor ``comp`` leaves of d on the held-out rows after its least-squares fit
    to d on the training rows (best of its starts)."""
    best = float(d_h @ d_h)
    for (s_tr, s_h), neg in zip(comp["starts"], comp["negative"]):
        S_tr = np.column_stack([s_tr] + [x[0] for x in comp["steps"]])
        S_h = np.column_stack([s_h] + [x[1] for x in comp["steps"]])
        keep = np.linalg.norm(S_tr, axis=0) > 0
        if not keep[0]:
            continue
        # the start's direction scaled by a >= 0 unless the effect may change sign (as the
        # finder's bounded fit and plausibility check allow); the steps of further parameters free
        lo = np.full(int(keep.sum()), -np.inf)
        if not neg:
            lo[0] = 0.0
        a = lsq_linear(S_tr[:, keep], d_tr, bounds=(lo, np.full(lo.size, np.inf))).x
        r = d_h - S_h[:, keep] @ a
        best = min(best, float(r @ r))
    return best


def identifiability(problem: FitProblem, spec_c: dict, mechs: list[Mechanism],
                    min_distinct: float = MIN_DISTINCT, comps: list[dict] | None = None) -> list[dict]:
    """For every mechanism with a vocabulary word: its best competitor, the share of the
    calibrated twin's held-out SSE that competitor leaves unexplained (``distinct``), and
    whether that is at least ``min_distinct`` (``identifiable``); mechanisms without a word
    get ``identifiable`` None. ``comps``: :func:`competitor_directions` if already computed."""
    y_c = problem.outputs(spec_c)
    r_c = problem.weighted_residual(y_c)
    sse_h = float(np.sum(r_c[:, problem.n_train:] ** 2))
    comps = comps if comps is not None else competitor_directions(problem, spec_c, y_c)
    rows = []
    for m in mechs:
        if not m.expect:
            rows.append({"mechanism": m.label, "expected": None, "identifiable": None,
                         "competitor": None, "distinct": None, "removal_share": None})
            continue
        s = copy.deepcopy(spec_c)
        m.remove(s)
        d_tr, d_h = _split(problem, problem.weighted_residual(problem.outputs(s)) - r_c)
        left = [(_left(d_tr, d_h, c), c["key"]) for c in comps if c["key"] != m.expect]
        worst, key = min(left) if left else (float(d_h @ d_h), None)
        rows.append({"mechanism": m.label, "expected": m.expect, "competitor": key,
                     "distinct": worst / sse_h, "removal_share": float(d_h @ d_h) / sse_h,
                     "identifiable": bool(worst / sse_h >= min_distinct)})
    return rows
