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
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from .arx import ArxModel, ArxOrders, RankDeficientError, fit_arx

CRITERIA = ("mdl", "mdl_as_printed", "aic", "bic")


def criterion_value(criterion: str, residuals: np.ndarray, orders: ArxOrders) -> float:
    """Score of one candidate (smaller is better) from its validation residuals."""
    r = np.asarray(residuals, dtype=float)
    r = r[np.isfinite(r)]
    n = r.size
    if n == 0:
        return math.inf
    v = float(np.mean(r ** 2))
    d = orders.n_params
    if criterion == "mdl":
        return v * (1.0 + d * math.log(n) / n)
    if criterion == "mdl_as_printed":
        n_ord = orders.order_sum
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
                          scored: np.ndarray, state_updates: bool = False) -> np.ndarray:
    if state_updates:   # the TALC predictor: measured outputs replace predictions
        pred = model.simulate(u, y, split, measured=scored, y_measured=y)
    else:               # pure simulation mode from the end of the training part
        pred = model.simulate(u, y, split)
    res = y[split:] - pred[split:]
    return res[scored[split:]]


def select_orders(*args, **kwargs) -> "OrderSelection":
    """See :func:`_select_orders`; runs with single-threaded BLAS: the hundreds of small
    least-squares problems are 10-100x slower with a multi-threaded BLAS on a busy machine."""
    with threadpool_limits(limits=1, user_api="blas"):
        return _select_orders(*args, **kwargs)


def _select_orders(y: np.ndarray, u: np.ndarray, na_range: tuple[int, int], nb_range: tuple[int, int],
                  *, nk: int = 0, intercept: bool = False, criterion: str = "mdl",
                  train_fraction: float = 0.6, weights: np.ndarray | None = None,
                  measured: np.ndarray | None = None, exhaustive_limit: int = 4000,
                  refit_on_all: bool = True, require_stable: bool = True,
                  state_updates: bool = False, max_pole_radius: float = 1.0,
                  real_positive_poles: bool = False) -> OrderSelection:
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
    ``state_updates``: validate with the TALC predictor (measured outputs replace the
    predictions, scored at the next measured samples) instead of pure simulation; this is
    how the model is used between sparse measurements after the calibration phase.
    Raises :class:`RankDeficientError` if no candidate is identifiable.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion: {criterion!r} is not one of {list(CRITERIA)}")
    if not 0 < max_pole_radius <= 1:
        raise ValueError(f"max_pole_radius: {max_pole_radius} must be in (0, 1]")
    margin = 1.0 - max_pole_radius
    if not 0.1 <= train_fraction <= 0.95:
        raise ValueError(f"train_fraction: {train_fraction} must be within [0.1, 0.95]")
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    if not np.all(np.isfinite(u)):
        raise ValueError("inputs u: non-finite values (hold or drop unavailable inputs first)")
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
    cache: dict[tuple, tuple[float, ArxModel | None, float]] = {}
    deficient = 0

    def evaluate(na: int, nb: tuple[int, ...]) -> float:
        nonlocal deficient
        key = (na, nb)
        if key in cache:
            return cache[key][0]
        orders = ArxOrders(na, nb, nk, intercept)
        if orders.n_params == 0:
            cache[key] = (math.inf, None, math.nan)
            return math.inf
        try:
            m = fit_arx(y, u, orders, weights, start=start, stop=split)
        except RankDeficientError:
            deficient += 1
            cache[key] = (math.inf, None, math.nan)
            return math.inf
        if require_stable and not m.is_stable(margin, real_positive_poles):
            cache[key] = (math.inf, None, math.nan)
            return math.inf
        res = _validation_residuals(m, y, u, split, scored, state_updates)
        s = criterion_value(criterion, res, orders)
        if not math.isfinite(s):
            s = math.inf
        rms = float(np.sqrt(np.mean(res ** 2))) if res.size else math.nan
        cache[key] = (s, m, rms)
        return s

    na_values = range(na_lo, na_hi + 1)
    nb_values = range(nb_lo, nb_hi + 1)
    n_candidates = len(na_values) * len(nb_values) ** r
    if n_candidates <= exhaustive_limit:
        for na in na_values:
            for nb in itertools.product(nb_values, repeat=r):
                evaluate(na, tuple(nb))
    else:
        # coordinate search from the smallest orders
        cur_na, cur_nb = na_lo, [nb_lo] * r
        best = evaluate(cur_na, tuple(cur_nb))
        improved = True
        while improved:
            improved = False
            for na in na_values:
                s = evaluate(na, tuple(cur_nb))
                if s < best:
                    best, cur_na, improved = s, na, True
            for j in range(r):
                for nb in nb_values:
                    trial = list(cur_nb)
                    trial[j] = nb
                    s = evaluate(cur_na, tuple(trial))
                    if s < best:
                        best, cur_nb, improved = s, trial, True

    finite = [(v[0], ArxOrders(k[0], k[1], nk, intercept).n_params, k) for k, v in cache.items()
              if math.isfinite(v[0])]
    if not finite:
        raise RankDeficientError(f"order selection: none of {len(cache)} candidates is identifiable "
                                 f"on {split - start} training rows", rank=0, n_params=max_orders.n_params)
    best_score = min(f[0] for f in finite)
    # ties (within 1e-9 relative) go to the smallest model
    tol = 1e-9 * max(1.0, abs(best_score))
    _, _, best_key = min((f for f in finite if f[0] <= best_score + tol), key=lambda f: (f[1], f[0]))
    score, model, rms = cache[best_key]
    orders = model.orders
    if refit_on_all:
        try:
            full = fit_arx(y, u, orders, weights, start=start)
            if full.is_stable(margin, real_positive_poles) or not require_stable:
                model = full
        except RankDeficientError:
            pass
    model.extra["validation_rms"] = rms
    return OrderSelection(model, orders, score, rms, len(cache), deficient)
