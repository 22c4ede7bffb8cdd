"""ARX order selection: fit every order combination and score it (Blaser thesis §4.2.2).

Procedure (thesis §4.2.2, §6.2.2): split the data chronologically, ``train_fraction`` (60 %)
for estimation and the rest for validation; fit each candidate (n_a, n_b,1 .. n_b,r) by
weighted least squares on the training part; run it in *simulation mode* (predictions fed
back, measured outputs only as initial conditions) over the validation part; score the
validation residuals at the samples whose output was measured; keep the smallest score.
Ties go to the model with fewer parameters.

Criteria (``criterion``), V = mean squared validation residual, N = validation residuals,
d = number of parameters:

- ``"mdl"`` (default): Rissanen's MDL as the thesis cites it (Rissanen [99]) and as MATLAB's
  ``selstruc`` computes it, V * (1 + d ln N / N).
- ``"mdl_as_printed"``: Eq. 4.23 literally, E_RMS * (1 + ln(N_ord) / N_ord) with
  N_ord = n_a + sum n_b,i. Kept for reproduction only: its factor *decreases* for
  N_ord >= 3, so it rewards larger orders instead of penalising them (see spec §2.5 [GAP]).
- ``"aic"``: N ln V + 2 d;  ``"bic"``: N ln V + d ln N.

Candidates whose training regression matrix is rank deficient, or (by default) whose
estimate is unstable, are skipped. An exhaustive
search is used while the grid has at most ``exhaustive_limit`` candidates; above that a
coordinate search (one order at a time, repeated until no improvement) is used, which
needs far fewer fits for the n_b <= 20 grids of the thesis's 144 h experiment.

Speed: the candidates are scored in batches (:mod:`talc_model.arx.batch`: one QR of the
largest regression matrix per n_a, stacked small solves with lstsq's rank tolerance, one
vectorised pole check and simulation); a coordinate sweep is one batch. The winner (and any
candidate tied with it to rounding) is fitted and scored again by the per-candidate code
(:func:`fit_arx`, :meth:`ArxModel.simulate`), so orders, model, score and RMS are those of the
per-candidate selection, kept as :func:`_select_orders_reference` for the tests; the
batched scores agree with it to ~1e-12 relative. ~20-40x faster for the 1,000-2,000
candidates of Table 6.1 (:mod:`thermal_eval.bench.order_selection`).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from talc_model.arx.model import ArxModel, ArxOrders, RankDeficientError, as_finite_input_matrix, fit_arx, input_gains_admissible
from talc_model.arx.batch import SharedRegression, input_lag_matrix, poles_inside, simulate_batch
from talc_model.arx.observer import ObserverScoring, observer_predictions
from thermal_comp_common.runtime.blas_threads import single_thread_blas

CRITERIA = ("mdl", "mdl_as_printed", "aic", "bic")


def criterion_value(criterion: str, residuals: np.ndarray, orders: ArxOrders) -> float:
    """Score of one candidate (smaller is better) from its validation residuals."""
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    n = r.size
    if n == 0:
        return math.inf
    return _criterion_from_mse(criterion, float(np.mean(r ** 2)), n, orders.n_params, orders.order_sum)


def _criterion_from_mse(criterion: str, v: float, n: int, d: int, n_ord: int) -> float:
    """The criterion from V (mean squared finite residual), N (their number, > 0), the number
    of parameters d and the order sum n_ord = n_a + sum n_b,i."""
    if criterion == "mdl":
        return v * (1.0 + d * math.log(n) / n)
    if criterion == "mdl_as_printed":
        if n_ord <= 0:
            return math.sqrt(v)
        return math.sqrt(v) * (1.0 + math.log(n_ord) / n_ord)
    v = max(v, 1e-300)
    if criterion == "aic":
        return n * math.log(v) + 2 * d
    if criterion == "bic":
        return n * math.log(v) + d * math.log(n)
    raise ValueError(f"criterion: {criterion!r} is not one of {list(CRITERIA)}")


@dataclass
class OrderSelection:
    """Result of :func:`select_orders`."""

    model: ArxModel              # refitted on all the data with the chosen orders
    orders: ArxOrders
    score: float
    validation_rms: float        # simulation-mode RMS on the validation part
    candidates_tried: int
    candidates_rank_deficient: int


def _validation_residuals(model: ArxModel, y: np.ndarray, u: np.ndarray, split: int,
                          scored: np.ndarray, state_updates: bool | ObserverScoring = False) -> np.ndarray:
    if isinstance(state_updates, ObserverScoring):   # TALC's predictor with its observer update
        pred = observer_predictions(model, u, y, split, scored, state_updates.noise_var, state_updates.window)
    elif state_updates:   # the thesis's TALC predictor: measured outputs replace predictions
        pred = model.simulate(u, y, split, measured=scored, y_measured=y)
    else:               # pure simulation mode from the end of the training part
        pred = model.simulate(u, y, split)
    res = y[split:] - pred[split:]
    return res[scored[split:]]


def select_orders(*args, **kwargs) -> "OrderSelection":
    """See :func:`_select_orders`; runs with single-threaded BLAS: the hundreds of small
    least-squares problems are 10-100x slower with a multi-threaded BLAS on a busy machine."""
    with single_thread_blas():
        return _select_orders(*args, **kwargs)


def _select_orders_reference(*args, **kwargs) -> "OrderSelection":
    """:func:`select_orders` with one :func:`fit_arx` and one :meth:`ArxModel.simulate` per
    candidate (the implementation before the batched one). Kept as the reference the
    batched evaluation is tested against; not for production use (~100x slower)."""
    with single_thread_blas():
        return _select_orders(*args, _batched=False, **kwargs)


@dataclass(frozen=True)
class _ScoringProblem:
    """What every candidate of one order selection is fitted and scored on."""

    y: np.ndarray
    u: np.ndarray                # N x r, finite
    nb_max: int
    nk: int
    intercept: bool
    weights: np.ndarray | None
    start: int                   # first training row (largest lag of the largest orders)
    split: int                   # training rows [start, split), validation from split on
    scored: np.ndarray           # validation residuals are scored where True
    state_updates: bool | ObserverScoring
    criterion: str
    margin: float                # poles must lie within radius 1 - margin
    real_positive_poles: bool
    require_stable: bool
    max_input_gain_ratio: float = math.inf


def _scoring_problem(y: np.ndarray, u: np.ndarray, na_range: tuple[int, int], nb_range: tuple[int, int],
                     *, nk: int = 0, intercept: bool = False, criterion: str = "mdl",
                     train_fraction: float = 0.6, weights: np.ndarray | None = None,
                     measured: np.ndarray | None = None, require_stable: bool = True,
                     state_updates: bool = False, max_pole_radius: float = 1.0,
                     real_positive_poles: bool = False, max_input_gain_ratio: float = math.inf) -> _ScoringProblem:
    """Check the arguments of :func:`select_orders` and split the data (see there)."""
    if criterion not in CRITERIA:
        raise ValueError(f"criterion: {criterion!r} is not one of {list(CRITERIA)}")
    if not 0 < max_pole_radius <= 1:
        raise ValueError(f"max_pole_radius: {max_pole_radius} must be in (0, 1]")
    if not 0.1 <= train_fraction <= 0.95:
        raise ValueError(f"train_fraction: {train_fraction} must be within [0.1, 0.95]")
    if not max_input_gain_ratio >= 1:
        raise ValueError(f"max_input_gain_ratio: {max_input_gain_ratio} must be >= 1 (inf = no bound)")
    y = np.asarray(y, dtype=float)
    u = as_finite_input_matrix(u)
    n, r = u.shape
    na_lo, na_hi = int(na_range[0]), int(na_range[1])
    nb_lo, nb_hi = int(nb_range[0]), int(nb_range[1])
    if na_lo < 0 or na_hi < na_lo or nb_lo < 0 or nb_hi < nb_lo:
        raise ValueError(f"order ranges: na {na_range}, nb {nb_range} are not valid (min <= max, >= 0)")
    scored = np.isfinite(y) if measured is None else (np.asarray(measured, bool) & np.isfinite(y))
    split = int(round(train_fraction * n))
    # simulation starts from measured outputs: move the split back past missing samples
    while split > 0 and not np.all(np.isfinite(y[max(0, split - max(na_hi, 1)):split])):
        split -= 1
    max_orders = ArxOrders(na_hi, (nb_hi,) * r, nk, intercept)
    # common first row so that every candidate is scored on the same samples
    start = max_orders.max_lag
    if split <= start:
        raise RankDeficientError(f"order selection: {n} samples leave no training rows after the "
                                 f"largest lag {start}", rank=0, n_params=max_orders.n_params)
    return _ScoringProblem(y, u, nb_hi, nk, intercept, weights, start, split, scored, state_updates,
                           criterion, 1.0 - max_pole_radius, real_positive_poles, require_stable,
                           float(max_input_gain_ratio))


class _PerCandidateScorer:
    """Scores candidates one by one: fit_arx, is_stable, ArxModel.simulate, criterion_value."""

    def __init__(self, problem: _ScoringProblem):
        self.p = problem
        self.deficient_keys: set[tuple] = set()

    def evaluate(self, key: tuple) -> tuple[float, ArxModel | None, float]:
        """(score, model fitted on the training part, validation RMS) of candidate ``key``."""
        p = self.p
        na, nb = key
        orders = ArxOrders(na, nb, p.nk, p.intercept)
        if orders.n_params == 0:
            return math.inf, None, math.nan
        try:
            m = fit_arx(p.y, p.u, orders, p.weights, start=p.start, stop=p.split)
        except RankDeficientError:
            self.deficient_keys.add(key)
            return math.inf, None, math.nan
        if p.require_stable and not m.is_stable(p.margin, p.real_positive_poles):
            return math.inf, None, math.nan
        if not m.input_gains_admissible(p.max_input_gain_ratio):
            return math.inf, None, math.nan
        res = _validation_residuals(m, p.y, p.u, p.split, p.scored, p.state_updates)
        s = criterion_value(p.criterion, res, orders)
        if not math.isfinite(s):
            s = math.inf
        rms = float(np.sqrt(np.mean(res ** 2))) if res.size else math.nan
        return s, m, rms

    def scores(self, keys: list[tuple]) -> list[float]:
        return [self.evaluate(k)[0] for k in keys]


class _BatchedScorer:
    """Scores many candidates at once with :mod:`talc_model.arx.batch`; same verdicts and
    (to rounding) the same scores as :class:`_PerCandidateScorer`."""

    #: bytes of the (validation steps x candidates) arrays of one simulated chunk
    CHUNK_BYTES = 32 * 2 ** 20

    def __init__(self, problem: _ScoringProblem):
        p = self.p = problem
        self.deficient_keys: set[tuple] = set()
        self._groups: dict[int, SharedRegression] = {}
        self._u_val = input_lag_matrix(p.u, p.nb_max, p.nk, p.intercept, p.split)   # (T, P_u)
        self._y_val = p.y[p.split:]
        self._scored_val = p.scored[p.split:]
        # the state update replaces predictions at measured samples (if there are any)
        self._replace = self._scored_val if p.state_updates and np.any(self._scored_val) else None

    def _group(self, na: int) -> SharedRegression:
        p = self.p
        if na not in self._groups:
            self._groups[na] = SharedRegression(p.y, p.u, na, p.nb_max, p.nk, p.intercept,
                                                p.weights, p.start, p.split)
        return self._groups[na]

    def scores(self, keys: list[tuple]) -> list[float]:
        out = [math.inf] * len(keys)
        by_na: dict[int, list[int]] = {}
        for i, (na, _) in enumerate(keys):
            by_na.setdefault(na, []).append(i)
        for na, members in by_na.items():
            nbs = np.array([keys[i][1] for i in members], dtype=int).reshape(len(members), self.p.u.shape[1])
            n_params = na + nbs.sum(axis=1) + int(self.p.intercept)
            g = self._group(na)
            theta, full_rank = g.fit(nbs)
            self.deficient_keys.update(keys[members[i]] for i in np.flatnonzero(~full_rank & (n_params > 0)))
            keep = full_rank.copy()
            if self.p.require_stable:
                keep &= poles_inside(theta[:, :na], self.p.margin, self.p.real_positive_poles)
            if math.isfinite(self.p.max_input_gain_ratio):
                r_in, nbm = self.p.u.shape[1], self.p.nb_max
                b = theta[:, na:na + r_in * nbm].reshape(theta.shape[0], r_in, nbm)
                keep &= np.all(input_gains_admissible(np.abs(b).sum(axis=2), b.sum(axis=2),
                                                      self.p.max_input_gain_ratio), axis=1)
            idx = np.flatnonzero(keep)
            chunk = max(1, self.CHUNK_BYTES // (8 * max(1, self._y_val.size)))
            for c0 in range(0, idx.size, chunk):
                sel = idx[c0:c0 + chunk]
                v, n = self._validation_mse(na, theta[sel])
                for i, vi, ni in zip(sel, v, n):
                    key = keys[members[i]]
                    if ni == 0:
                        continue
                    n_ord = na + sum(key[1])
                    s = _criterion_from_mse(self.p.criterion, float(vi), int(ni),
                                            n_ord + int(self.p.intercept), n_ord)
                    out[members[i]] = s if math.isfinite(s) else math.inf
        return out

    def _validation_mse(self, na: int, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean squared finite validation residual and their number, per candidate."""
        with np.errstate(over="ignore", invalid="ignore"):
            bu = self._u_val @ theta[:, na:].T                               # (T, M)
            pred = simulate_batch(theta[:, :na], bu, self.p.y[self.p.split - na:self.p.split],
                                  self._replace, self._y_val)
            res = self._y_val[self._scored_val, None] - pred[self._scored_val]
            finite = np.isfinite(res)
            n = finite.sum(axis=0)
            sq = np.where(finite, res, 0.0) ** 2
            v = sq.sum(axis=0) / np.maximum(n, 1)
        return v, n


# Over 80 lines only by its 8-line signature and its docstring: the body is one pass (check,
# score every candidate, search, refit the winner).
def _select_orders(y: np.ndarray, u: np.ndarray, na_range: tuple[int, int], nb_range: tuple[int, int],
                  *, nk: int = 0, intercept: bool = False, criterion: str = "mdl",
                  train_fraction: float = 0.6, weights: np.ndarray | None = None,
                  measured: np.ndarray | None = None, exhaustive_limit: int = 4000,
                  refit_on_all: bool = True, require_stable: bool = True,
                  state_updates: bool = False, max_pole_radius: float = 1.0,
                  real_positive_poles: bool = False, max_input_gain_ratio: float = math.inf,
                  _batched: bool = True) -> OrderSelection:
    """Choose ARX orders for output ``y`` and inputs ``u`` (N x r) by ``criterion``.

    ``na_range``/``nb_range`` are inclusive (min, max); the same n_b range applies to every
    input. ``measured[k]`` marks samples whose output was measured (validation is scored
    there only; default all). ``weights`` are the WLS weights of the training fit.
    The chosen model is refitted on all data (``refit_on_all``, kept only if still stable)
    before it is returned. With ``require_stable`` candidates whose A(q) has a pole on or
    outside the unit circle are skipped: a thermal system is stable, and an unstable
    recursion fed back in simulation mode diverges between measurements.
    ``max_pole_radius`` (< 1) tightens this to |pole| < max_pole_radius, i.e. no time
    constant longer than -step / ln(max_pole_radius): a near-unit pole fitted to noise makes
    the simulation drift like an integrator between measurements. ``real_positive_poles``
    also skips candidates with complex or negative poles (see :meth:`ArxModel.is_stable`).
    ``max_input_gain_ratio`` (inf = off) skips candidates with an input whose coefficients
    sum in absolute value to more than this many times their net (static) gain
    (:meth:`ArxModel.input_gain_ratios`): a differentiator fitted to slow data amplifies a
    faster input change than any it was fitted on.
    ``state_updates``: validate with the TALC predictor (measured outputs replace the
    predictions, scored at the next measured samples) instead of pure simulation; this is
    how the model is used between sparse measurements after the calibration phase. An
    :class:`~talc_model.arx.observer.ObserverScoring` instead corrects the state at each
    measured sample by TALC's observer (the loop's update); those candidates are scored one
    by one (the observer's covariance recursion is not batched).
    Raises :class:`RankDeficientError` if no candidate is identifiable.

    Candidates are scored in batches (:mod:`talc_model.arx.batch`, ``_batched``); the
    winner is then fitted and scored once more per candidate (:func:`fit_arx`,
    :meth:`ArxModel.simulate`), so the returned model, score and RMS are those of the
    per-candidate evaluation (:func:`_select_orders_reference`).
    """
    problem = _scoring_problem(y, u, na_range, nb_range, nk=nk, intercept=intercept, criterion=criterion,
                               train_fraction=train_fraction, weights=weights, measured=measured,
                               require_stable=require_stable, state_updates=state_updates,
                               max_pole_radius=max_pole_radius, real_positive_poles=real_positive_poles,
                               max_input_gain_ratio=max_input_gain_ratio)
    y, u, start, margin = problem.y, problem.u, problem.start, problem.margin
    r = u.shape[1]
    _batched = _batched and not isinstance(state_updates, ObserverScoring)
    reference = _PerCandidateScorer(problem)
    scorer = _BatchedScorer(problem) if _batched else reference
    cache: dict[tuple, float] = {}      # the candidates the search asked for, in that order
    ahead: dict[tuple, float] = {}      # scored in advance, not (yet) asked for

    def score_ahead(keys: list[tuple]) -> None:
        todo = [k for k in dict.fromkeys(keys) if k not in cache and k not in ahead]
        if todo:
            ahead.update(zip(todo, scorer.scores(todo)))

    def scores(keys: list[tuple]) -> list[float]:
        score_ahead(keys)
        for k in keys:
            if k not in cache:
                cache[k] = ahead.pop(k)
        return [cache[k] for k in keys]

    _search(scores, range(int(na_range[0]), int(na_range[1]) + 1),
            range(int(nb_range[0]), int(nb_range[1]) + 1), r, exhaustive_limit,
            score_ahead if _batched else None)

    # ties (within 1e-9 relative) go to the smallest model, then to the smallest score
    best_key, score, model, rms = _winner(cache, nk, intercept, reference, _batched)
    if best_key is None:
        largest = ArxOrders(int(na_range[1]), (problem.nb_max,) * r, nk, intercept)
        raise RankDeficientError(f"order selection: none of {len(cache)} candidates is identifiable "
                                 f"on {problem.split - start} training rows", rank=0,
                                 n_params=largest.n_params)
    orders = model.orders
    if refit_on_all:
        try:
            full = fit_arx(y, u, orders, weights, start=start)
            if (full.is_stable(margin, real_positive_poles) or not require_stable) \
                    and full.input_gains_admissible(problem.max_input_gain_ratio):
                model = full
        except RankDeficientError:
            pass
    model.extra["validation_rms"] = rms
    deficient = sum(1 for k in cache if k in scorer.deficient_keys)
    return OrderSelection(model, orders, score, rms, len(cache), deficient)


def _winner(cache: dict[tuple, float], nk: int, intercept: bool, reference: _PerCandidateScorer,
            batched: bool) -> tuple:
    """(key, score, model, rms) of the best candidate in ``cache`` ((None, ..) if none).

    Ties within 1e-9 relative of the best score go to the fewest parameters, then to the
    smallest score. With batched scores, the candidates this last step could pick (fewest
    parameters, score within rounding of the smallest; several only when distinct orders give
    the same model, e.g. collinear inputs) are scored again per candidate and the choice is
    made on those scores, as the per-candidate selection makes it; a candidate the
    per-candidate fit rejects (rank or stability verdict flipped by rounding at its boundary)
    is dropped and the choice repeated.
    """
    while True:
        finite = [(s, k[0] + sum(k[1]) + int(intercept), k) for k, s in cache.items()
                  if math.isfinite(s)]
        if not finite:
            return None, math.inf, None, math.nan
        best_score = min(f[0] for f in finite)
        tol = 1e-9 * max(1.0, abs(best_score))
        ties = [f for f in finite if f[0] <= best_score + tol]
        d_min = min(f[1] for f in ties)
        if not batched:
            _, _, key = min(ties, key=lambda f: (f[1], f[0]))
            return (key, *reference.evaluate(key))
        s_min = min(f[0] for f in ties if f[1] == d_min)
        contenders = [f[2] for f in ties if f[1] == d_min and f[0] <= s_min + tol]
        confirmed = []
        for key in contenders:
            score, model, rms = reference.evaluate(key)
            if model is None or not math.isfinite(score):
                cache[key] = math.inf
            else:
                confirmed.append((score, key, model, rms))
        if len(confirmed) == len(contenders):   # else: choose again without the rejected ones
            score, key, model, rms = min(confirmed, key=lambda c: c[0])   # first of equal ones
            return key, score, model, rms


def _search(scores, na_values: range, nb_values: range, r: int, exhaustive_limit: int,
            score_ahead=None) -> None:
    """Exhaustive search while the grid has at most ``exhaustive_limit`` candidates, else a
    coordinate search from the smallest orders (one order at a time, repeated until no
    improvement). ``scores(keys)`` scores a list of (na, nb) at once. In a coordinate round
    the candidates of the remaining sweeps are known as long as no sweep improves, so
    ``score_ahead(keys)`` (if given) is handed all of them before each sweep: one batch per
    round and per improvement instead of one per sweep. Which candidates count as tried, and
    in which order, is decided by ``scores`` alone."""
    n_candidates = len(na_values) * len(nb_values) ** r
    if n_candidates <= exhaustive_limit:
        scores([(na, tuple(nb)) for na in na_values for nb in itertools.product(nb_values, repeat=r)])
        return

    def sweep_keys(na: int, nb: tuple, j: int) -> list[tuple]:
        return [(na, nb[:j] + (v,) + nb[j + 1:]) for v in nb_values]

    def look_ahead(na: int, nb: tuple, first_j: int, with_na: bool) -> None:
        if score_ahead is not None:
            keys = [(v, nb) for v in na_values] if with_na else []
            for j in range(first_j, r):
                keys += sweep_keys(na, nb, j)
            score_ahead(keys)

    cur_na, cur_nb = na_values[0], (nb_values[0],) * r
    look_ahead(cur_na, cur_nb, 0, True)
    best = scores([(cur_na, cur_nb)])[0]
    improved = True
    while improved:
        improved = False
        look_ahead(cur_na, cur_nb, 0, True)
        trials = [(na, cur_nb) for na in na_values]
        for (na, _), s in zip(trials, scores(trials)):
            if s < best:
                best, cur_na, improved = s, na, True
        for j in range(r):
            look_ahead(cur_na, cur_nb, j, False)
            trials = sweep_keys(cur_na, cur_nb, j)
            for (_, nb), s in zip(trials, scores(trials)):
                if s < best:
                    best, cur_nb, improved = s, nb, True
