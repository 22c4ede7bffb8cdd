"""MISO ARX models: regression matrix, weighted least squares, full-rank check, prediction.

One model per error component (Blaser thesis §4.1, Eqs 4.3, 4.15-4.20)::

    E[k] + a1 E[k-1] + ... + a_na E[k-na]
         = sum_i ( b_i,0 u_i[k-nk] + ... + b_i,nb_i-1 u_i[k-nk-nb_i+1] ) (+ c) + e[k]

Conventions (the thesis is inconsistent here, see spec §2.3 [GAP]):

- ``nb[i]`` is the *number* of coefficients of input i (MATLAB ``arx`` [na nb nk]); with
  the default delay ``nk = 0`` the current input u[k] (b0) is included, as in the thesis's
  worked examples (4.24), (4.26). ``nk = 1`` drops b0 (Eq. 4.15 as printed).
- ``nb[i] = 0`` removes input i from the model.
- The intercept ``c`` is optional and off by default (all signals are deltas from the start).
- theta = [a1 .. a_na, b_1,0 .. b_1,nb1-1, b_2,0 .., c] and the regressor is
  phi[k] = [-E[k-1] .. -E[k-na], u_1[k-nk] .., u_2[k-nk] .., 1]  (thesis sign convention).

Parameters are estimated by (weighted) least squares through ``numpy.linalg.lstsq`` on
sqrt(W)-scaled rows (Eq. 4.20), after a full-rank check of the regression matrix with the
SVD tolerance of ``numpy.linalg.matrix_rank`` (= MATLAB ``rank``, thesis §6.2.1).

Simulation mode (thesis §4.2, validation): past *predictions* are fed back as the
autoregressive outputs; wherever a measured output is known it replaces the prediction
(the TALC state update, §6.2.2).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal


class RankDeficientError(ValueError):
    """The (weighted) regression matrix has no full column rank: the model is not identifiable."""

    def __init__(self, message: str, rank: int, n_params: int):
        super().__init__(message)
        self.rank = rank
        self.n_params = n_params


@dataclass(frozen=True)
class ArxOrders:
    """Orders of one MISO ARX model."""

    na: int
    nb: tuple[int, ...]
    nk: int = 0
    intercept: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "nb", tuple(int(n) for n in self.nb))
        if self.na < 0:
            raise ValueError(f"ArxOrders.na: {self.na} must be >= 0")
        if self.nk < 0:
            raise ValueError(f"ArxOrders.nk: {self.nk} must be >= 0")
        if any(n < 0 for n in self.nb):
            raise ValueError(f"ArxOrders.nb: {self.nb} must all be >= 0")

    @property
    def n_inputs(self) -> int:
        return len(self.nb)

    @property
    def n_params(self) -> int:
        return self.na + sum(self.nb) + int(self.intercept)

    @property
    def order_sum(self) -> int:
        """n_a + sum of n_b,i: the 'N' of the thesis's Eq. 4.23 and its minimum CP length."""
        return self.na + sum(self.nb)

    @property
    def max_lag(self) -> int:
        """Samples of history needed before the first regression row."""
        lags = [self.na] + [self.nk + n - 1 for n in self.nb if n > 0]
        return max(lags)

    def to_state(self) -> dict:
        return {"na": self.na, "nb": list(self.nb), "nk": self.nk, "intercept": self.intercept}

    @classmethod
    def from_state(cls, d: dict) -> "ArxOrders":
        return cls(int(d["na"]), tuple(d["nb"]), int(d.get("nk", 0)), bool(d.get("intercept", False)))


def _check_signals(y: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    if y.ndim != 1:
        raise ValueError(f"output y: expected a 1-D array, got shape {y.shape}")
    if u.ndim != 2 or u.shape[0] != y.shape[0]:
        raise ValueError(f"inputs u: expected shape ({y.shape[0]}, n_inputs), got {u.shape}")
    return y, u


def regression_matrix(y: np.ndarray, u: np.ndarray, orders: ArxOrders,
                      start: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regression matrix Phi, target and the sample indices k of its rows.

    Rows run from ``start`` (default: ``orders.max_lag``) to the end; rows that contain a
    non-finite value are kept (callers decide; :func:`fit_arx` drops them).
    """
    y, u = _check_signals(y, u)
    if u.shape[1] != orders.n_inputs:
        raise ValueError(f"inputs u: {u.shape[1]} columns, orders have {orders.n_inputs} inputs")
    n = y.shape[0]
    k0 = orders.max_lag if start is None else max(int(start), orders.max_lag)
    rows = np.arange(k0, n)
    cols = []
    for i in range(1, orders.na + 1):
        cols.append(-y[rows - i])
    for j, nb in enumerate(orders.nb):
        for lag in range(orders.nk, orders.nk + nb):
            cols.append(u[rows - lag, j])
    if orders.intercept:
        cols.append(np.ones(rows.shape[0]))
    phi = np.column_stack(cols) if cols else np.zeros((rows.shape[0], 0))
    return phi, y[rows], rows


def check_full_rank(phi: np.ndarray, what: str = "regression matrix") -> int:
    """Raise :class:`RankDeficientError` unless ``phi`` has full column rank; return the rank."""
    n_params = phi.shape[1]
    if phi.shape[0] < n_params:
        raise RankDeficientError(f"{what}: {phi.shape[0]} usable rows for {n_params} parameters",
                                 rank=min(phi.shape), n_params=n_params)
    rank = int(np.linalg.matrix_rank(phi)) if n_params else 0
    if rank < n_params:
        raise RankDeficientError(f"{what}: rank {rank} < {n_params} parameters (not identifiable yet)",
                                 rank=rank, n_params=n_params)
    return rank


def solve_wls(phi: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
              what: str = "regression matrix") -> np.ndarray:
    """theta = argmin sum W[k] (target[k] - phi[k] theta)^2 (Eq. 4.20), full rank required."""
    if weights is None:
        weights = np.ones(phi.shape[0])
    weights = np.asarray(weights, dtype=float)
    if weights.shape != (phi.shape[0],):
        raise ValueError(f"weights: shape {weights.shape}, expected ({phi.shape[0]},)")
    if np.any(weights < 0) or not np.all(np.isfinite(weights)):
        raise ValueError("weights: must be finite and >= 0")
    keep = weights > 0
    sw = np.sqrt(weights[keep])
    a = phi[keep] * sw[:, None]
    b = target[keep] * sw
    n_params = a.shape[1]
    if a.shape[0] < n_params:
        raise RankDeficientError(f"{what}: {a.shape[0]} usable rows for {n_params} parameters",
                                 rank=min(a.shape), n_params=n_params)
    # lstsq's SVD gives the rank with matrix_rank's default tolerance (rcond=None:
    # max(M, N) * eps * s_max), so the full-rank check costs no second decomposition
    theta, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    if rank < n_params:
        raise RankDeficientError(f"{what}: rank {rank} < {n_params} parameters (not identifiable yet)",
                                 rank=int(rank), n_params=n_params)
    return theta


@dataclass
class ArxModel:
    """A fitted MISO ARX model."""

    orders: ArxOrders
    theta: np.ndarray
    #: standard deviation of the (weighted) equation error on the fit data
    residual_std: float = float("nan")
    n_fit_samples: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def a(self) -> np.ndarray:
        return self.theta[: self.orders.na]

    @property
    def b(self) -> list[np.ndarray]:
        out, i = [], self.orders.na
        for nb in self.orders.nb:
            out.append(self.theta[i:i + nb])
            i += nb
        return out

    @property
    def c(self) -> float:
        return float(self.theta[-1]) if self.orders.intercept else 0.0

    def poles(self) -> np.ndarray:
        """Poles of 1/A(q) (empty for n_a = 0)."""
        if self.orders.na == 0:
            return np.zeros(0, dtype=complex)
        return np.roots(np.concatenate(([1.0], self.a))).astype(complex)

    def is_stable(self, margin: float = 0.0, real_positive: bool = False) -> bool:
        """True if every pole of 1/A(q) lies inside the unit circle (radius 1 - margin).

        ``real_positive`` also requires every pole to be real and > 0, as for heat conduction:
        a linear thermal network has a symmetric negative-definite system matrix, so its
        continuous-time eigenvalues are real and negative and its sampled poles exp(lambda T)
        lie in (0, 1). Complex or negative poles make the simulation oscillate (with a period
        of a few samples for negative ones), which a thermal error never does.
        """
        p = self.poles()
        if p.size == 0:
            return True
        ok = np.abs(p) < 1.0 - margin
        if real_positive:
            ok &= (np.abs(p.imag) <= 1e-6) & (p.real > 0)
        return bool(np.all(ok))

    def input_gain_ratios(self) -> np.ndarray:
        """Per input: sum |b_i| / |sum b_i| (1 for a single coefficient, inf for a zero static
        gain with non-zero coefficients, 0 for an input the model does not use).

        A large ratio is a differentiator: lags of large, opposite coefficients whose net
        (static) effect is small. It amplifies input changes faster than any seen in the data
        it was fitted on (see :func:`talc_model.arx.order_selection.select_orders`,
        ``max_input_gain_ratio``)."""
        out = []
        for bj in self.b:
            out.append(_gain_ratio(np.abs(bj).sum(), bj.sum()))
        return np.array(out, dtype=float)

    def input_gains_admissible(self, max_ratio: float) -> bool:
        """No input's coefficients sum in absolute value to more than ``max_ratio`` times their
        net gain (:func:`input_gains_admissible`; inf: always true)."""
        b = self.b
        return bool(np.all(input_gains_admissible(np.array([np.abs(x).sum() for x in b]),
                                                  np.array([x.sum() for x in b]), max_ratio)))

    def input_part(self, u: np.ndarray) -> np.ndarray:
        """B(q) u[k] (+ c) for every k >= the largest input lag (NaN before)."""
        u = np.asarray(u, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
        n = u.shape[0]
        out = np.full(n, self.c)
        for j, bj in enumerate(self.b):
            if bj.size == 0:
                continue
            # full convolution, then shift by the delay nk
            conv = np.convolve(u[:, j], bj)[:n]
            shifted = np.full(n, np.nan)
            shifted[self.orders.nk:] = conv[: n - self.orders.nk]
            shifted[: self.orders.nk + bj.size - 1] = np.nan
            out = out + shifted
        return out

    def predict_one(self, y_past: np.ndarray, u_hist: np.ndarray, k: int) -> float:
        """Prediction of E[k] from the outputs y_past[k-1], ... and the inputs u_hist[..k]."""
        o = self.orders
        val = self.c
        for i in range(1, o.na + 1):
            val -= self.theta[i - 1] * y_past[k - i]
        p = o.na
        for j, nb in enumerate(o.nb):
            for lag in range(o.nk, o.nk + nb):
                val += self.theta[p] * u_hist[k - lag, j]
                p += 1
        return float(val)

    def simulate(self, u: np.ndarray, y_init: np.ndarray, start: int,
                 measured: np.ndarray | None = None, y_measured: np.ndarray | None = None
                 ) -> np.ndarray:
        """Simulation-mode prediction for k = start .. len(u)-1.

        ``y_init`` gives the outputs before ``start`` (at least ``na`` of them). From
        ``start`` on, predictions are fed back; where ``measured[k]`` is true the value
        ``y_measured[k]`` replaces the prediction in the fed-back history (state update)
        *after* the prediction for k has been recorded. Returns the predictions (NaN
        before ``start``).
        """
        y, bu = self.simulation_start(u, y_init, start, "simulate")
        n = len(bu)
        pred = np.full(n, np.nan)
        if measured is None or not np.any(measured[start:]) or self.orders.na == 0:
            pred[start:] = self.free_run(bu, y, start, n)
            return pred
        # between measurements the recursion is an IIR filter: run it segment by segment,
        # each segment starting from the history (measured values replacing predictions)
        meas_idx = np.flatnonzero(np.asarray(measured[start:], bool)) + start
        seg_starts = [start] + [int(m) + 1 for m in meas_idx if m + 1 < n]
        seg_ends = [int(m) + 1 for m in meas_idx] + [n]
        for s0, s1 in zip(seg_starts, seg_ends):
            if s1 <= s0:
                continue
            pred[s0:s1] = y[s0:s1] = self.free_run(bu, y, s0, s1)
            last = s1 - 1
            if measured[last]:
                y[last] = y_measured[last]
        return pred

    def simulation_start(self, u: np.ndarray, y_init: np.ndarray, start: int, who: str
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The output history (``y_init`` before ``start``, NaN after) and the input part of
        ``u`` for a simulation from ``start``; ``who`` names the caller in the error."""
        u = np.asarray(u, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
        if start < self.orders.max_lag:
            raise ValueError(f"{who}: start {start} is before the model's largest lag {self.orders.max_lag}")
        y = np.full(u.shape[0], np.nan)
        y[:start] = np.asarray(y_init, dtype=float)[:start]
        return y, self.input_part(u)

    def free_run(self, bu: np.ndarray, y: np.ndarray, s0: int, s1: int) -> np.ndarray:
        """Predictions for k = s0 .. s1-1 fed back on their own from the history ``y[:s0]``:
        an IIR filter, vectorised by scipy.signal.lfilter."""
        na = self.orders.na
        if na == 0:
            return bu[s0:s1].copy()
        den = np.concatenate(([1.0], self.a))
        zi = signal.lfiltic([1.0], den, y[s0 - na:s0][::-1])
        return signal.lfilter([1.0], den, bu[s0:s1], zi=zi)[0]

    def to_state(self) -> dict:
        return {"orders": self.orders.to_state(), "theta": self.theta.tolist(),
                "residual_std": self.residual_std, "n_fit_samples": self.n_fit_samples,
                "extra": self.extra}

    @classmethod
    def from_state(cls, d: dict) -> "ArxModel":
        orders = ArxOrders.from_state(d["orders"])
        theta = np.asarray(d["theta"], dtype=float)
        if theta.shape != (orders.n_params,):
            raise ValueError(f"ARX state: 'theta' has {theta.size} values, orders need {orders.n_params}")
        return cls(orders, theta, float(d.get("residual_std", np.nan)),
                   int(d.get("n_fit_samples", 0)), dict(d.get("extra", {})))


def as_finite_input_matrix(u: np.ndarray) -> np.ndarray:
    """``u`` as a float (N x r) matrix; non-finite inputs raise (identification needs them held
    or dropped first)."""
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    if not np.all(np.isfinite(u)):
        raise ValueError("inputs u: non-finite values (hold or drop unavailable inputs first)")
    return u


def _gain_ratio(abs_sum: float, net: float) -> float:
    if abs_sum <= 1e-300:
        return 0.0
    return abs_sum / abs(net) if net != 0 else float("inf")


def input_gains_admissible(b_abs_sum: np.ndarray, b_net: np.ndarray, max_ratio: float) -> np.ndarray:
    """Elementwise: sum |b| <= max_ratio * |sum b| (with a 1e-12 allowance for unused inputs)."""
    if not np.isfinite(max_ratio):
        return np.ones(np.shape(b_abs_sum), dtype=bool)
    return np.asarray(b_abs_sum) <= max_ratio * np.abs(b_net) + 1e-12


def fit_arx(y: np.ndarray, u: np.ndarray, orders: ArxOrders, weights: np.ndarray | None = None,
            start: int | None = None, stop: int | None = None,
            what: str = "ARX regression matrix") -> ArxModel:
    """Fit an ARX model by (weighted) least squares on the rows k in [start, stop).

    ``weights[k]`` weighs the equation of sample k (the sample whose output is the target).
    Rows with a non-finite value or zero weight are left out. Raises
    :class:`RankDeficientError` if the remaining regression matrix has no full rank.
    """
    y, u = _check_signals(y, u)
    phi, target, rows = regression_matrix(y, u, orders, start)
    w = np.ones(y.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != y.shape:
        raise ValueError(f"weights: shape {w.shape}, expected {y.shape}")
    w = w[rows]
    if stop is not None:
        w = np.where(rows < stop, w, 0.0)
    ok = np.isfinite(target) & np.all(np.isfinite(phi), axis=1) & (w > 0)
    phi, target, w = phi[ok], target[ok], w[ok]
    theta = solve_wls(phi, target, w, what)
    res = target - phi @ theta
    dof = max(1, phi.shape[0] - orders.n_params)
    std = float(np.sqrt(np.sum(w * res ** 2) / np.sum(w) * phi.shape[0] / dof)) if phi.shape[0] else np.nan
    return ArxModel(orders, theta, std, int(phi.shape[0]))
