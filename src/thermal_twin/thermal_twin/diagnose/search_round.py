"""One search round of the mismatch finder on the task engine: screen, fit, test, rank.

The candidates of a round are independent: each is screened (:func:`mismatch_fit.screen_one`)
and the shortlist fitted (:func:`mismatch_fit.fit_candidate`) as tasks of
:func:`thermal_comp_common.runtime.task_engine.map_tasks` (serial by default, a local process pool or
a Dask cluster). A candidate holds closures (its edit of the description), which a process
pool cannot send: a task names its candidate by its index and the worker rebuilds the round's
candidate list from :class:`RoundInputs` (what the round shares: recording, base description,
its outputs, drivers), once per worker. Results are put back in the candidates' order before
anything is ranked, so the answer does not depend on the engine or on completion order.

After the rounds, what the greedy search adopted is refitted together and pruned on held-out
data (:func:`prune`). The search adopts one effect per round, each fitted on top of the ones before it with their
values fixed: with two effects concealed, the first is fitted while the second is still
missing, and its values carry the second's share (a conductance 12 % high, a channel it
does not act on made worse). So:

0. **Exchange** (:func:`exchange`): with several effects adopted, the first was chosen while
   the second was still missing, so a near rival of the first (a coolant where a heat source
   was adopted, a neighbouring node) can be the better choice once the second is there. The
   best few supported hypotheses of every round are tried in place of its adopted one, each
   set refitted together on the training window; the set with the lowest held-out weighted
   sum of squares (the rounds' own ranking, no longer conditioned on a first choice made
   without the second effect) that leaves no channel worse replaces the greedy one.
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
import itertools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_twin.diagnose.effects import EFFECTS, Candidate, DriverInfo, candidates
from thermal_twin.diagnose.fit import (FitProblem, Hypothesis, acted_improvement_pct, fit_candidate, screen_one,
                                      worse_channels)
from thermal_twin.diagnose.locate import operating_regimes
from thermal_twin.machine.schema import MachineSpecError
from thermal_twin.diagnose.significance import holm_reject


@dataclass
class RoundInputs:
    """What every task of a round shares (sent once per worker)."""

    problem: FitProblem
    base_spec: dict
    y0_full: np.ndarray                 # the base description's outputs, (channels, time)
    drivers: dict[str, DriverInfo]
    channels: list[str]
    effects: tuple[str, ...] = EFFECTS
    _cands: list | None = field(default=None, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)   # base node states (screening)

    def __getstate__(self) -> dict:     # candidates and cache are rebuilt where the tasks run
        state = dict(self.__dict__)
        state["_cands"], state["_cache"] = None, {}
        return state

    def candidates(self) -> list[Candidate]:
        """The round's candidates, in the library's order (built once per process)."""
        if self._cands is None:
            self._cands = candidates(self.base_spec, self.drivers, self.channels, self.effects)
        return self._cands


def _screen_task(shared: RoundInputs, i: int) -> tuple[float, int]:
    """(screening share, twin runs) of one candidate."""
    p = shared.problem
    n0 = p.n_evals
    y0 = shared.y0_full[:, :p.n_train]
    if "r0" not in shared._cache:
        shared._cache["r0"] = p.train_residual(y0).ravel()
    err = screen_one(p, shared.base_spec, shared.candidates()[i], y0, shared._cache["r0"], shared._cache)
    return err, p.n_evals - n0


def _fit_task(shared: RoundInputs, item: tuple[int, float]) -> tuple[Hypothesis | None, int]:
    """(fitted hypothesis without its candidate and description, twin runs) of one candidate;
    the caller puts both back (they do not travel between processes)."""
    i, err = item
    p = shared.problem
    n0 = p.n_evals
    h = fit_candidate(p, shared.base_spec, shared.candidates()[i], shared.y0_full, err)
    if h is not None:
        h = dataclasses.replace(h, candidate=None, spec=None)
    return h, p.n_evals - n0


def _ordered(fn, shared: RoundInputs, items: list, engine: EngineSpec | None,
             progress: Callable[[], None] | None = None) -> list:
    """``fn`` over ``items`` on the engine, results in the items' order; the twin runs of
    the tasks are added to the round's problem (whichever process ran them)."""
    out: list = [None] * len(items)
    n0 = shared.problem.n_evals
    runs = 0
    for i, (result, n) in map_tasks(fn, shared, items, engine):
        out[i] = result
        runs += n
        if progress:
            progress()
    shared.problem.n_evals = n0 + runs
    return out


def _shortlist(ranked: list[tuple[float, Candidate]], shortlist: int, keep_share: float) -> list[tuple[float, Candidate]]:
    """Every candidate whose screening share is at least ``keep_share`` of the best (at least
    3, at most ``shortlist``), plus the best of every effect type."""
    best_err = ranked[0][0] if ranked else 0.0
    chosen: dict[str, tuple[float, Candidate]] = {}
    for err, c in ranked[:shortlist]:
        if err >= keep_share * best_err or len(chosen) < 3:
            chosen[c.key] = (err, c)
    seen: set = set()
    for err, c in ranked:
        if err > 0 and c.effect not in seen:
            seen.add(c.effect)
            chosen.setdefault(c.key, (err, c))
    return list(chosen.values())


def run_round(inputs: RoundInputs, shortlist: int = 10, min_improvement_pct: float = 5.0,
              round_no: int = 1, progress: Callable[[], None] | None = None, keep_share: float = 0.2,
              engine: EngineSpec | None = None) -> tuple[list[Hypothesis], int]:
    """Screen every candidate, fit the shortlist, test on held-out data with Holm's
    correction over all candidates screened, rank. Returns (hypotheses best first, number
    of candidates screened)."""
    cands = inputs.candidates()
    errs = _ordered(_screen_task, inputs, list(range(len(cands))), engine, progress)
    ranked = sorted(zip(errs, cands), key=lambda e: -e[0])      # stable: ties keep library order
    chosen = _shortlist(ranked, shortlist, keep_share)
    index = {id(c): i for i, c in enumerate(cands)}
    fitted = _ordered(_fit_task, inputs, [(index[id(c)], err) for err, c in chosen], engine)
    hyps = []
    for (_, c), h in zip(chosen, fitted):
        if h is not None:
            h.candidate, h.spec, h.round = c, c.apply(inputs.base_spec, h.values), round_no
            hyps.append(h)
    for h, ok in zip(hyps, holm_reject([h.p_value for h in hyps], len(cands))):
        h.holm_pass = ok
    hyps.sort(key=lambda h: h.rank_key(min_improvement_pct))
    mark_indistinguishable(hyps, problem=inputs.problem)
    return hyps, len(cands)


def mark_indistinguishable(hyps: list[Hypothesis], corr_threshold: float = 0.95,
                           margin_pct: float = 5.0, problem: FitProblem | None = None) -> None:
    """Flag plausible hypotheses whose fitted output changes are nearly collinear and whose
    held-out improvements are within ``margin_pct`` points: this data cannot tell them apart.
    With ``problem``, each flagged pair also records what would tell them apart
    (:func:`tell_apart`)."""
    good = [h for h in hyps if h.plausible and h.change is not None and np.any(h.change)]
    for i, a in enumerate(good):
        for b in good[i + 1:]:
            if abs(a.holdout_improvement_pct - b.holdout_improvement_pct) > margin_pct:
                continue
            na, nb = np.linalg.norm(a.change), np.linalg.norm(b.change)
            if na == 0 or nb == 0:
                continue
            if float(a.change @ b.change) / (na * nb) >= corr_threshold:
                a.indistinguishable_from.append(b.candidate.key)
                b.indistinguishable_from.append(a.candidate.key)
                if problem is not None:
                    way = tell_apart(problem, a, b)
                    a.tell_apart.append({"other": b.candidate.key, **way})
                    b.tell_apart.append({"other": a.candidate.key, **way})


def tell_apart(problem: FitProblem, a: Hypothesis, b: Hypothesis) -> dict:
    """Where two indistinguishable fits differ most: the channel with the largest RMS of the
    difference of their fitted changes (in noise sigmas; below one sigma no recorded channel
    tells them apart and a sensor at one of the targets would), and the operating regime in
    which the difference on that channel is largest per sample (a recording with more of it
    would)."""
    n_ch = len(problem.channels)
    d = (a.change - b.change).reshape(n_ch, -1)
    rms = np.sqrt(np.mean(d ** 2, axis=1))
    k = int(np.argmax(rms))
    idx = np.arange(0, problem.n_train, problem.stride)[:d.shape[1]]
    rec = problem.recording
    regimes = operating_regimes(rec.time_s[idx], {n: np.asarray(v)[idx] for n, v in rec.inputs.items()})
    per = {}
    for name, mask in regimes.items():
        for label, m in ((name, mask), (f"not {name}", ~mask)):
            if 0 < m.sum() < m.size:
                per[label] = float(np.sqrt(np.mean(d[k, m] ** 2)))
    regime = max(per, key=per.get) if per else None
    return {"channel": problem.channels[k], "difference_rms_sigma": float(rms[k]),
            "regime": regime, "regime_difference_rms_sigma": per.get(regime) if regime else None,
            "recorded_channel_tells_apart": bool(rms[k] >= 1.0)}


# --- after the rounds: refit together, each pays for itself, never worse -------------------
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


#: rivals of a round's adopted effect tried in its place by :func:`exchange` (with it, at most)
EXCHANGE_TOP = 4


def _rivals(hyps: list[Hypothesis], adopted: Hypothesis, min_improvement_pct: float, top: int) -> list[Hypothesis]:
    """The adopted hypothesis and the best other supported ones of its round (ranked first)."""
    out = [adopted]
    for h in sorted(hyps, key=lambda h: h.rank_key(min_improvement_pct)):
        if len(out) >= top:
            break
        if h is not adopted and h.supported(min_improvement_pct):
            out.append(h)
    return out


def exchange(problem: FitProblem, base: dict, y_base: np.ndarray, rounds: list[list[Hypothesis]],
             adopted: list[Hypothesis], min_improvement_pct: float, top: int = EXCHANGE_TOP
             ) -> tuple[list[Hypothesis], dict | None]:
    """Try the best ``top`` supported hypotheses of every round in place of its adopted one
    (``rounds[i]`` holds round i+1's hypotheses, ``adopted[i]`` its choice), every set
    refitted together (:func:`refit`); the set with the lowest held-out weighted sum of squares
    among those leaving no channel worse than ``y_base`` wins (the greedy set on a tie). Returns
    (the set, with its joint values and cumulative descriptions; a record of the exchange or
    None when the greedy set stays)."""
    if len(adopted) < 2:
        return adopted, None
    nt = problem.n_train
    alts = [_rivals(hyps, a, min_improvement_pct, top) for hyps, a in zip(rounds, adopted)]
    best, greedy_sse = None, None
    for combo in itertools.product(*alts):
        if len({(h.candidate.effect, h.candidate.target) for h in combo}) < len(combo):
            continue
        combo = list(combo)
        greedy = all(h is a for h, a in zip(combo, adopted))
        try:    # a round's candidate edits a description that may lack what another round added
            vals = refit(problem, base, combo)
            y = problem.outputs(_spec(base, combo, vals))
        except (MachineSpecError, KeyError, ValueError):
            continue
        if not greedy and worse_channels(problem, y_base, y):
            continue
        sse = float(np.sum(problem.weighted_residual(y, nt) ** 2))
        if greedy:
            greedy_sse = sse
        if best is None or sse < best[0] or (sse == best[0] and greedy):
            best = (sse, combo, vals, greedy)
    if best is None or best[3] or greedy_sse is None:
        return adopted, None
    sse, combo, vals, _ = best
    out = [dataclasses.replace(h, values=v, spec=_spec(base, combo[:i + 1], vals[:i + 1]))
           for i, (h, v) in enumerate(zip(combo, vals))]
    return out, {"greedy": [h.candidate.key for h in adopted], "exchanged": [h.candidate.key for h in combo],
                 "holdout_sse_greedy": greedy_sse, "holdout_sse_exchanged": sse}


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
