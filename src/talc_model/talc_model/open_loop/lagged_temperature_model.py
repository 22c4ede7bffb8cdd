"""Open-loop thermo-elastic model on temperatures and their exponentially weighted history.

Physics: a structure's thermal displacement follows the temperatures of its parts, and
each part's mean temperature lags the measured surface temperature by a first-order
diffusion delay. So a displacement is, to first order, a linear combination of the sensor
temperatures and of first-order low-pass filtered copies of them (time constants tau_j):

    E(t) = c + sum_i sum_j w_ij * LP_tau_j[T_i - T_i(0)](t)          (tau_0 = 0: the raw value)

(This is the "lagged, exponentially weighted temperature history" practitioners ask for;
an ARX model with b-terms only and one pole per time constant is the same structure.)
The weights are found by ridge regression on standardised features; the time constants
and the ridge penalty are hyper-parameters, chosen by walk-forward validation on the
training data only (:func:`walk_forward_select`). No displacement is ever needed after
training: predictions are open loop.

Filters are causal and exact for samples at irregular intervals (a_k = exp(-dt_k / tau)),
started at the first sample's value, so predicting a later window means running the
filter over the temperatures from the start of the recording (never over displacements).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import signal
from sklearn.base import BaseEstimator


class LaggedModelError(ValueError):
    """Bad input to the lagged-temperature model; the message names the argument and value."""


def exponential_filter(time_s: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """Causal first-order low-pass of each column of ``x`` (N x m) with time constant ``tau_s``.

    Zero-order hold between samples: y_k = a_k y_{k-1} + (1 - a_k) x_k, a_k = exp(-dt_k/tau),
    started at the first sample (y_0 = x_0). The step response from 0 to 1 is therefore
    1 - exp(-(t_k - t_0 + dt) / tau) sampled after each hold, i.e. exact for a piecewise-constant
    input. NaN inputs hold the filter state (a missing reading does not pull it anywhere).
    Uniform steps without NaN run through ``scipy.signal.lfilter`` (same recursion).
    """
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        return exponential_filter(t, x[:, None], tau_s)[:, 0]
    if not (math.isfinite(tau_s) and tau_s >= 0):
        raise LaggedModelError(f"tau_s: {tau_s!r} must be a finite time >= 0 s")
    if t.ndim != 1 or t.shape[0] != x.shape[0]:
        raise LaggedModelError(f"time_s has {t.shape[0] if t.ndim == 1 else t.shape} samples, x has {x.shape[0]}")
    if tau_s == 0 or x.shape[0] == 0:
        return x.copy()
    dt = np.diff(t)
    if np.any(~np.isfinite(dt)) or np.any(dt <= 0):
        bad = int(np.flatnonzero(~(dt > 0))[0]) + 1
        raise LaggedModelError(f"time_s: sample {bad} ({t[bad]!r}) does not increase (previous {t[bad - 1]!r})")
    if dt.size and np.all(np.isfinite(x)) and np.ptp(dt) <= 1e-9 * dt[0]:
        a = math.exp(-dt[0] / tau_s)
        # y_k - a y_{k-1} = (1 - a) x_k with the state started at x_0
        zi = (a * x[0])[None, :]
        out = np.empty_like(x)
        out[0] = x[0]
        if x.shape[0] > 1:
            out[1:], _ = signal.lfilter([1.0 - a], [1.0, -a], x[1:], axis=0, zi=zi)
        return out
    out = np.empty_like(x)
    state = x[0].copy()
    state[~np.isfinite(state)] = 0.0
    a = np.exp(-np.concatenate([[0.0], dt]) / tau_s)
    for k in range(x.shape[0]):
        xk = x[k]
        ok = np.isfinite(xk)
        state[ok] = a[k] * state[ok] + (1.0 - a[k]) * xk[ok]
        out[k] = state
    return out


def lagged_features(time_s: np.ndarray, temperatures: np.ndarray, taus_s: Sequence[float],
                    reference: np.ndarray | None = None, exogenous: np.ndarray | None = None,
                    exogenous_taus_s: Sequence[float] = ()) -> np.ndarray:
    """Feature matrix of the model, causal in time (row k uses rows <= k only).

    Column blocks: [T - T_ref, LP_tau1(T - T_ref), ...] (N x m*(1+len(taus))), then, if
    ``exogenous`` (N x q machine inputs, e.g. spindle speed) is given,
    [u - u_0, LP_tau(u - u_0) for tau in exogenous_taus_s]. NaN features become 0 (= reference).
    """
    T = np.asarray(temperatures, dtype=float)
    if T.ndim != 2:
        raise LaggedModelError(f"temperatures: expected an N x m array, got shape {T.shape}")
    ref = T[0] if reference is None else np.asarray(reference, dtype=float)
    if ref.shape != (T.shape[1],):
        raise LaggedModelError(f"reference: {ref.shape[0] if ref.ndim else ref!r} values for {T.shape[1]} sensors")
    d = T - ref
    blocks = [d] + [exponential_filter(time_s, d, tau) for tau in taus_s]
    if exogenous is not None:
        u = np.asarray(exogenous, dtype=float)
        u = u[:, None] if u.ndim == 1 else u
        if u.shape[0] != T.shape[0]:
            raise LaggedModelError(f"exogenous: {u.shape[0]} samples, temperatures have {T.shape[0]}")
        du = u - u[0]
        blocks += [du] + [exponential_filter(time_s, du, tau) for tau in exogenous_taus_s]
    X = np.hstack(blocks)
    return np.where(np.isfinite(X), X, 0.0)


class LaggedTemperatureModel(BaseEstimator):
    """Ridge regression of one error channel on lagged temperature (and machine-input) features.

    scikit-learn conventions: the hyper-parameters are the constructor's arguments (checked by
    ``fit``), ``fit(X, y)`` on a feature matrix returns the model, ``predict(X)``, fitted
    attributes end in ``_``. ``features(time_s, temperatures, exogenous)`` builds X from a
    recording (relative to ``reference_``, the first row seen by :meth:`fit_recording`);
    :meth:`fit_recording` / :meth:`predict_recording` do both steps. ``exogenous_taus_s`` is used
    only when exogenous inputs are passed.
    """

    def __init__(self, taus_s: Sequence[float] = (1800.0, 7200.0), alpha: float = 10.0,
                 exogenous_taus_s: Sequence[float] = ()):
        self.taus_s = taus_s
        self.alpha = alpha
        self.exogenous_taus_s = exogenous_taus_s

    def _checked_params(self) -> tuple[tuple[float, ...], float, tuple[float, ...]]:
        taus = tuple(float(t) for t in self.taus_s)
        exo_taus = tuple(float(t) for t in self.exogenous_taus_s)
        if not (isinstance(self.alpha, (int, float)) and math.isfinite(self.alpha) and self.alpha >= 0):
            raise LaggedModelError(f"alpha: {self.alpha!r} must be a finite number >= 0")
        for name, v in (("taus_s", taus), ("exogenous_taus_s", exo_taus)):
            if any(not (math.isfinite(t) and t >= 0) for t in v):
                raise LaggedModelError(f"{name}: {v!r} must be finite times >= 0 s")
        return taus, float(self.alpha), exo_taus

    def features(self, time_s: np.ndarray, temperatures: np.ndarray,
                 exogenous: np.ndarray | None = None) -> np.ndarray:
        taus, _, exo_taus = self._checked_params()
        return lagged_features(time_s, temperatures, taus, getattr(self, "reference_", None), exogenous, exo_taus)

    def fit(self, X: np.ndarray, y: np.ndarray) -> "LaggedTemperatureModel":
        """Ridge fit on standardised features (closed-form normal equations, deterministic)."""
        _, alpha, _ = self._checked_params()
        X = np.asarray(X, dtype=float)
        y = np.asarray(y, dtype=float)
        if X.ndim != 2 or X.shape[0] != y.shape[0]:
            raise LaggedModelError(f"X has shape {X.shape}, y has {y.shape[0]} samples")
        ok = np.isfinite(y)
        if ok.sum() < 2:
            raise LaggedModelError(f"y: only {int(ok.sum())} finite samples, need >= 2 to fit")
        if alpha == 0 and ok.sum() <= X.shape[1]:
            raise LaggedModelError(f"y: {int(ok.sum())} finite samples for {X.shape[1]} features "
                                   f"without regularisation (alpha = 0)")
        Xo, yo = X[ok], y[ok]
        self.mean_ = Xo.mean(axis=0)
        sd = Xo.std(axis=0)
        self.scale_ = np.where(sd > 1e-12, sd, 1.0)
        Z = (Xo - self.mean_) / self.scale_
        ym = float(yo.mean())
        A = Z.T @ Z + alpha * np.eye(Z.shape[1])
        self.coef_ = np.linalg.lstsq(A, Z.T @ (yo - ym), rcond=None)[0] if alpha == 0 \
            else np.linalg.solve(A, Z.T @ (yo - ym))
        self.intercept_ = ym
        return self

    def fit_recording(self, time_s: np.ndarray, temperatures: np.ndarray, y: np.ndarray,
                      exogenous: np.ndarray | None = None) -> "LaggedTemperatureModel":
        """Features of a recording (relative to its first row), then :meth:`fit`."""
        self.reference_ = np.asarray(temperatures, dtype=float)[0].copy()
        return self.fit(self.features(time_s, temperatures, exogenous), y)

    def predict(self, X: np.ndarray) -> np.ndarray:
        coef = getattr(self, "coef_", None)
        if coef is None:
            raise LaggedModelError("model is not fitted")
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != coef.size:
            raise LaggedModelError(f"X has shape {X.shape}, the model has {coef.size} features")
        return self.intercept_ + ((X - self.mean_) / self.scale_) @ coef

    def predict_recording(self, time_s: np.ndarray, temperatures: np.ndarray,
                          exogenous: np.ndarray | None = None) -> np.ndarray:
        """Open-loop prediction; run the features from the start of the recording (causal filters)."""
        return self.predict(self.features(time_s, temperatures, exogenous))


def walk_forward_folds(n_train: int, n_folds: int = 4, min_train_fraction: float = 0.5) -> list[tuple[int, int, int]]:
    """(fit_end, val_start, val_end) row indices of expanding-window folds inside rows [0, n_train).

    The first fold fits on the first ``min_train_fraction`` of the training rows; the rest is
    cut into ``n_folds`` consecutive validation blocks, each scored by a model fitted on every
    row before it. No index reaches ``n_train``.
    """
    if not isinstance(n_folds, int) or n_folds < 1:
        raise LaggedModelError(f"n_folds: {n_folds!r} must be an integer >= 1")
    if not 0 < min_train_fraction < 1:
        raise LaggedModelError(f"min_train_fraction: {min_train_fraction!r} must be in (0, 1)")
    first = int(n_train * min_train_fraction)
    step = (n_train - first) // n_folds
    if step < 10:
        raise LaggedModelError(f"n_train: {n_train} rows are too few for {n_folds} folds of >= 10 rows")
    return [(first + i * step, first + i * step, first + (i + 1) * step if i < n_folds - 1 else n_train)
            for i in range(n_folds)]


@dataclass
class Selection:
    """Result of :func:`walk_forward_select`."""

    taus_s: tuple[float, ...]
    alpha: float
    mae_by_candidate: dict[str, float]          # mean walk-forward MAE per candidate
    fold_mae: list[float]                        # per-fold MAE of the chosen candidate
    best_mae: float
    folds: list[tuple[int, int, int]]


def walk_forward_select(time_s: np.ndarray, temperatures: np.ndarray, y: np.ndarray, n_train: int,
                        tau_grid: Sequence[Sequence[float]], alpha_grid: Sequence[float],
                        n_folds: int = 4, exogenous: np.ndarray | None = None,
                        exogenous_taus_s: Sequence[float] = (), progress=None) -> Selection:
    """Choose (taus, alpha) by the mean walk-forward MAE, using rows < ``n_train`` only.

    Every input is cut to its first ``n_train`` rows before anything else happens; each fold
    fits on rows [0, fit_end) and scores rows [val_start, val_end). Features are causal
    filters started at row 0, so no fold sees a later temperature either. ``progress`` is an
    optional callable run once per candidate time-constant set (e.g. a tqdm ``update``).
    """
    n = len(np.asarray(y))
    if not 0 < n_train <= n:
        raise LaggedModelError(f"n_train: {n_train} is not in 1..{n}")
    t = np.asarray(time_s, dtype=float)[:n_train]
    T = np.asarray(temperatures, dtype=float)[:n_train]
    yy = np.asarray(y, dtype=float)[:n_train]
    u = None if exogenous is None else np.asarray(exogenous, dtype=float)[:n_train]
    folds = walk_forward_folds(n_train, n_folds)
    if not tau_grid or not alpha_grid:
        raise LaggedModelError(f"tau_grid / alpha_grid: empty ({list(tau_grid)!r}, {list(alpha_grid)!r})")
    scores: dict[str, float] = {}
    best: tuple[float, tuple, float, list] = (math.inf, (), math.nan, [])
    for taus in tau_grid:
        taus = tuple(float(x) for x in taus)
        X = lagged_features(t, T, taus, exogenous=u, exogenous_taus_s=exogenous_taus_s)
        for alpha in alpha_grid:
            errs = []
            for fit_end, v0, v1 in folds:
                m = LaggedTemperatureModel(taus, float(alpha)).fit(X[:fit_end], yy[:fit_end])
                p = m.predict(X[v0:v1])
                ok = np.isfinite(yy[v0:v1])
                errs.append(float(np.mean(np.abs(p[ok] - yy[v0:v1][ok]))) if ok.any() else math.nan)
            mae = float(np.nanmean(errs))
            scores[f"taus={list(taus)},alpha={alpha:g}"] = mae
            if mae < best[0]:
                best = (mae, taus, float(alpha), errs)
        if progress is not None:
            progress()
    if not math.isfinite(best[0]):
        raise LaggedModelError("y: no fold has a finite displacement to score")
    return Selection(best[1], best[2], scores, best[3], best[0], folds)


#: Candidate time constants (s): bearing / spindle nose (10 min) up to the machine structure (8 h).
CANDIDATE_TAUS_S = (600.0, 1800.0, 3600.0, 7200.0, 14400.0, 28800.0)
#: Ridge penalties on standardised features (a few thousand training rows).
DEFAULT_ALPHA_GRID = (0.1, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5)


def default_tau_grid(taus: Sequence[float] = CANDIDATE_TAUS_S) -> list[tuple[float, ...]]:
    """Candidate time-constant sets: none (static), each single lag, each pair of lags."""
    taus = [float(t) for t in taus]
    grid: list[tuple[float, ...]] = [()]
    grid += [(a,) for a in taus]
    grid += list(itertools.combinations(taus, 2))
    return grid
