"""One search round of the mismatch finder on the task engine: screen, fit, test, rank.

The candidates of a round are independent: each is screened (:func:`mismatch_fit.screen_one`)
and the shortlist fitted (:func:`mismatch_fit.fit_candidate`) as tasks of
:func:`thermal_comp_common.runtime.task_engine.map_tasks` (serial by default, a local process pool or
a Dask cluster). A candidate holds closures (its edit of the description), which a process
pool cannot send: a task names its candidate by its index and the worker rebuilds the round's
candidate list from :class:`RoundInputs` (what the round shares: recording, base description,
its outputs, drivers), once per worker. Results are put back in the candidates' order before
anything is ranked, so the answer does not depend on the engine or on completion order.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_twin.diagnose.effects import EFFECTS, Candidate, DriverInfo, candidates
from thermal_twin.diagnose.fit import FitProblem, Hypothesis, fit_candidate, screen_one
from thermal_twin.diagnose.locate import operating_regimes
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
