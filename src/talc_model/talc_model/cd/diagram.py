"""Characteristic diagrams (CD): smoothed grid regression and the load-case update.

:class:`CharacteristicDiagram` is Priber's smoothed grid regression as used by Naumann,
Ihlenfeldt, Putz et al. (spec ``shared/spec/characteristic-diagrams.md``): tensor-product
multilinear kernels on an equidistant grid, weighted least squares plus second-difference
smoothing, inputs clamped to the grid. :func:`load_case_update` fits an additive update CD to a
new load case. Input selection: :mod:`talc_model.cd.input_selection`; the update from
measurements: :mod:`talc_model.cd.measurement_update`. Every reconstruction choice: docs/agp_cd.md.
No rclpy here; pure numpy/scipy.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from sklearn.base import BaseEstimator
from thermal_comp_common.metrics import rmse


class CharacteristicDiagramError(ValueError):
    """Bad input to a characteristic diagram; the message names the argument and value."""


def as_2d(u, name: str) -> np.ndarray:
    a = np.asarray(u, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise CharacteristicDiagramError(f"{name}: expected a (samples, inputs) array, got shape {a.shape}")
    return a


def _per_input(value, n: int, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.size == 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise CharacteristicDiagramError(f"{name}: {arr.size} values for {n} inputs")
    return arr


def second_difference_operator(shape: Sequence[int], axis: int) -> sp.csr_matrix:
    """Sparse operator of the second differences of a tensor grid along ``axis``.

    ``shape`` is the vertex count per dimension; rows are the interior vertices along ``axis``
    (vertices with 1 <= i_axis <= n-2), columns the flattened (C-order) vertex index.
    """
    shape = tuple(int(s) for s in shape)
    n = shape[axis]
    if n < 3:
        return sp.csr_matrix((0, int(np.prod(shape))))
    d2 = sp.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], [0, 1, 2], shape=(n - 2, n))
    mats = [sp.identity(s, format="csr") for s in shape]
    mats[axis] = d2
    op = mats[0]
    for m in mats[1:]:
        op = sp.kron(op, m, format="csr")
    return op.tocsr()


@dataclass
class CharacteristicDiagram(BaseEstimator):
    """A smoothed-grid-regression characteristic diagram y = f(u), u in R^D.

    Parameters
    ----------
    n_intervals: grid intervals per input (int or one per input); vertices = n + 1 per input.
    smoothing: dimensionless smoothing weight lambda (scalar or one per input; 0 = none).
    ridge: tiny Tikhonov weight relative to the data term, pins the smoothing null space.
    bounds: optional (lower, upper) arrays of the grid domain; default the training range.
    extrapolate: per input (or one for all): beyond the grid, continue the boundary cell linearly
        instead of clamping (for an input that is itself a model's prediction of the output, e.g. a
        soft sensor of the machine type, whose map stays linear beyond the training range).
    """

    n_intervals: int | Sequence[int] = 4
    smoothing: float | Sequence[float] = 1e-4
    ridge: float = 1e-9
    bounds: tuple[Sequence[float], Sequence[float]] | None = None
    extrapolate: bool | Sequence[bool] = False
    # fitted state (scikit-learn convention: set by fit, trailing underscore, not a parameter)
    lower_: np.ndarray | None = field(default=None, init=False, repr=False)
    upper_: np.ndarray | None = field(default=None, init=False, repr=False)
    shape_: tuple[int, ...] | None = field(default=None, init=False, repr=False)
    coef_: np.ndarray | None = field(default=None, init=False, repr=False)
    out_of_range_count_: int = field(default=0, init=False, repr=False)   # predictions clamped since fit

    # ---------------------------------------------------------------- geometry
    @property
    def n_inputs(self) -> int:
        if self.shape_ is None:
            raise CharacteristicDiagramError("characteristic diagram is not fitted")
        return len(self.shape_)

    def _cells(self, u: np.ndarray, count_out_of_range: bool = True):
        """Cell index and local coordinate tau in [0,1] per sample and input (clamped; beyond
        [0,1] along the ``extrapolate`` inputs: the boundary cell continued linearly)."""
        lo, hi = self.lower_, self.upper_
        n = np.asarray(self.shape_) - 1
        s = (u - lo) / (hi - lo) * n
        outside = (s < -1e-9) | (s > n + 1e-9)
        if count_out_of_range:
            self.out_of_range_count_ += int(np.any(outside, axis=1).sum())
        free = np.asarray(self.extrapolate, bool)
        s = np.where(free, s, np.clip(s, 0.0, n))
        idx = np.clip(np.floor(s).astype(int), 0, n - 1)
        tau = s - idx
        return idx, tau

    def basis_matrix(self, u, count_out_of_range: bool = False) -> sp.csr_matrix:
        """Sparse K x N matrix of the kernel values Phi_v(u_k) (<= 2^D non-zeros per row)."""
        u = as_2d(u, "u")
        if u.shape[1] != self.n_inputs:
            raise CharacteristicDiagramError(f"u: {u.shape[1]} inputs, diagram has {self.n_inputs}")
        idx, tau = self._cells(u, count_out_of_range)
        k, dim = u.shape
        strides = np.array([int(np.prod(self.shape_[d + 1:])) for d in range(dim)], dtype=int)
        rows, cols, vals = [], [], []
        for corner in itertools.product((0, 1), repeat=dim):
            b = np.asarray(corner)
            w = np.prod(np.where(b == 1, tau, 1.0 - tau), axis=1)
            col = ((idx + b) * strides).sum(axis=1)
            rows.append(np.arange(k))
            cols.append(col)
            vals.append(w)
        n_vertices = int(np.prod(self.shape_))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(k, n_vertices))

    # ---------------------------------------------------------------- fitting
    def fit(self, u, y, sample_weight=None) -> "CharacteristicDiagram":
        """Fit the vertex coefficients by weighted, smoothed least squares (R3-R6 of the digest);
        ``u``: samples x inputs (scikit-learn's X), ``sample_weight``: data weights (default 1)."""
        u = as_2d(u, "u")
        y = np.asarray(y, dtype=float).ravel()
        if y.shape[0] != u.shape[0]:
            raise CharacteristicDiagramError(f"y: {y.shape[0]} values for {u.shape[0]} samples")
        w = np.ones_like(y) if sample_weight is None else np.asarray(sample_weight, dtype=float).ravel()
        if w.shape != y.shape:
            raise CharacteristicDiagramError(f"sample_weight: {w.shape[0]} values for {y.shape[0]} samples")
        if np.any(w < 0) or not np.all(np.isfinite(w)):
            raise CharacteristicDiagramError("sample_weight: must be finite and >= 0")
        finite = np.all(np.isfinite(u), axis=1) & np.isfinite(y)
        if not finite.any():
            raise CharacteristicDiagramError("u/y: no sample with finite inputs and output")
        u, y, w = u[finite], y[finite], w[finite]
        if w.sum() <= 0:
            raise CharacteristicDiagramError("sample_weight: all zero")
        dim = u.shape[1]
        n = _per_input(self.n_intervals, dim, "n_intervals").astype(int)
        if np.any(n < 1):
            raise CharacteristicDiagramError(f"n_intervals: must be >= 1, got {n.tolist()}")
        lam = _per_input(self.smoothing, dim, "smoothing")
        if np.any(lam < 0):
            raise CharacteristicDiagramError(f"smoothing: must be >= 0, got {lam.tolist()}")
        if self.bounds is not None:
            lo = _per_input(self.bounds[0], dim, "bounds[0]")
            hi = _per_input(self.bounds[1], dim, "bounds[1]")
        else:
            lo, hi = u.min(axis=0), u.max(axis=0)
        span = hi - lo
        flat = span <= 1e-12 * np.maximum(1.0, np.abs(lo))
        hi = np.where(flat, lo + 1.0, hi)   # a constant input gets a unit-wide domain
        self.lower_, self.upper_ = lo, hi
        self.shape_ = tuple(int(v) + 1 for v in n)
        a = self.basis_matrix(u)
        wn = w / w.sum()                                    # data term = weighted mean square
        lhs = (a.T @ sp.diags(wn) @ a).tocsr()
        rhs = a.T @ (wn * y)
        n_vertices = a.shape[1]
        for d in range(dim):
            if lam[d] == 0 or self.shape_[d] < 3:
                continue
            s = second_difference_operator(self.shape_, d) * float(n[d]) ** 2   # d2f/ds2, s in [0,1]
            lhs = lhs + (lam[d] / s.shape[0]) * (s.T @ s)
        lhs = lhs + self.ridge * sp.identity(n_vertices, format="csr")
        if n_vertices <= 60000:
            self.coef_ = np.asarray(spla.spsolve(lhs.tocsc(), rhs)).ravel()
        else:
            self.coef_, _ = spla.cg(lhs, rhs, rtol=1e-10, maxiter=20 * n_vertices)
        self.out_of_range_count_ = 0
        return self

    def predict(self, u) -> np.ndarray:
        """Evaluate the diagram; inputs outside the grid are clamped or extrapolated (and counted)."""
        if self.coef_ is None:
            raise CharacteristicDiagramError("characteristic diagram is not fitted")
        u = as_2d(u, "u")
        bad = ~np.all(np.isfinite(u), axis=1)
        out = np.full(u.shape[0], np.nan)
        if (~bad).any():
            if u.shape[1] != self.n_inputs:
                raise CharacteristicDiagramError(f"u: {u.shape[1]} inputs, diagram has {self.n_inputs}")
            # cell-local form (R2): 2^D vertex look-ups per sample, no sparse matrix
            idx, tau = self._cells(u[~bad], count_out_of_range=True)
            dim = u.shape[1]
            strides = np.array([int(np.prod(self.shape_[d + 1:])) for d in range(dim)], dtype=int)
            acc = np.zeros(idx.shape[0])
            for corner in itertools.product((0, 1), repeat=dim):
                b = np.asarray(corner)
                w = np.prod(np.where(b == 1, tau, 1.0 - tau), axis=1)
                acc += w * self.coef_[((idx + b) * strides).sum(axis=1)]
            out[~bad] = acc
        return out

    def to_state(self) -> dict:
        if self.coef_ is None:
            raise CharacteristicDiagramError("characteristic diagram is not fitted")
        return {"n_intervals": [s - 1 for s in self.shape_],
                "smoothing": np.atleast_1d(self.smoothing).tolist(), "ridge": self.ridge,
                "lower": self.lower_.tolist(), "upper": self.upper_.tolist(),
                "coef": self.coef_.tolist(), "extrapolate": np.broadcast_to(
                    np.asarray(self.extrapolate, bool), (len(self.shape_),)).tolist()}

    @classmethod
    def from_state(cls, state: dict) -> "CharacteristicDiagram":
        try:
            cd = cls(n_intervals=list(state["n_intervals"]), smoothing=state["smoothing"],
                     ridge=float(state["ridge"]))
            cd.lower_ = np.asarray(state["lower"], dtype=float)
            cd.upper_ = np.asarray(state["upper"], dtype=float)
            cd.shape_ = tuple(int(v) + 1 for v in state["n_intervals"])
            cd.coef_ = np.asarray(state["coef"], dtype=float)
            cd.extrapolate = list(state.get("extrapolate", False)) if isinstance(state.get("extrapolate"), list) \
                else bool(state.get("extrapolate", False))
        except KeyError as exc:
            raise CharacteristicDiagramError(f"characteristic diagram state: missing key {exc}") from None
        if cd.coef_.size != int(np.prod(cd.shape_)):
            raise CharacteristicDiagramError(f"characteristic diagram state: 'coef' has {cd.coef_.size} "
                                             f"values, grid has {int(np.prod(cd.shape_))} vertices")
        return cd


def fit_with_grid_refinement(u, y, u_val, y_val, *, start_intervals: int = 1, max_intervals: int = 32,
                             min_relative_gain: float = 0.05, sample_weight=None,
                             smoothing: float | Sequence[float] = 1e-4) -> tuple[CharacteristicDiagram, list[dict]]:
    """[002 §3.2]: start coarse and equidistant, halve the grid elements until the validation
    RMSE improves by less than ``min_relative_gain`` (the paper's "no significant improvement";
    the threshold is our choice). Returns the best diagram and the refinement history."""
    history: list[dict] = []
    best: CharacteristicDiagram | None = None
    best_err = math.inf
    n = int(start_intervals)
    while n <= max_intervals:
        cd = CharacteristicDiagram(n_intervals=n, smoothing=smoothing).fit(u, y, sample_weight)
        err = rmse(cd.predict(u_val), y_val)
        history.append({"n_intervals": n, "val_rmse": err})
        if best is not None and not err < best_err * (1.0 - min_relative_gain):
            if err < best_err:
                best, best_err = cd, err
            break
        best, best_err = cd, err
        n *= 2
    assert best is not None
    return best, history


# ---------------------------------------------------------------------------------------
# Load-case-dependent update [002 §3.2]

@dataclass
class LoadCaseUpdate:
    """Result of :func:`load_case_update`: predict with ``base(u) + update.predict(u)``."""

    update: CharacteristicDiagram
    w_new: float                 # data weight of the new load case in the accepted fit
    rmse_reference: float        # RMSE on the new data of the CD fitted to the new data only
    rmse_new: float              # RMSE on the new data of the accepted update
    rmse_orig: float             # RMSE on the original data of the accepted update
    accepted: bool               # False: even the first weighted fit failed; the reference is returned
    iterations: list[dict]       # w_new, rmse_new, rmse_orig per iteration of the loop


def load_case_update(base_predict: Callable[[np.ndarray], np.ndarray], u_orig, y_orig, u_new, y_new, *,
                     make_cd: Callable[[], CharacteristicDiagram] | None = None,
                     w_orig: float = 1.0, w_new_initial: float = 10.0, decay: float = 0.7,
                     stop_factor: float = 2.0, rmse_floor: float = 0.0,
                     max_iterations: int = 50) -> LoadCaseUpdate:
    """Additive load-case update of a base model with the weight-decay loop of [002 §3.2].

    The update CD is fitted to the *residuals* y - base(u) ("limited disturbance of the original
    model": the original data's residuals act as anchors). Steps (paper's numbering):
    1. fit on the new residuals only -> reference, RMSE_ref on the new data;
    3'. w_orig = 1, w_new = 10;
    4. repeat: fit on the weighted union, RMSE_i on the new data; stop when
       RMSE_i > stop_factor * max(RMSE_ref, rmse_floor) and keep the last acceptable fit;
       else w_new *= decay.
    Gaps chosen here: RMSE_i is evaluated on the new data (implied by the paper's Step 1 remark);
    ``rmse_floor`` (e.g. the measurement resolution) keeps a near-perfect reference from making
    every fit unacceptable; if the first iteration already fails, the reference (new data only)
    is returned with ``accepted=False``; at most ``max_iterations`` iterations.
    """
    make_cd = make_cd or CharacteristicDiagram
    u_orig, u_new = as_2d(u_orig, "u_orig"), as_2d(u_new, "u_new")
    if u_orig.shape[1] != u_new.shape[1]:
        raise CharacteristicDiagramError(f"u_new: {u_new.shape[1]} inputs, u_orig has {u_orig.shape[1]}")
    if not 0 < decay < 1:
        raise CharacteristicDiagramError(f"decay: must be in (0, 1), got {decay}")
    r_orig = np.asarray(y_orig, dtype=float).ravel() - np.asarray(base_predict(u_orig), dtype=float).ravel()
    r_new = np.asarray(y_new, dtype=float).ravel() - np.asarray(base_predict(u_new), dtype=float).ravel()
    # the union's grid must span both data sets
    lo = np.minimum(u_orig.min(axis=0), u_new.min(axis=0))
    hi = np.maximum(u_orig.max(axis=0), u_new.max(axis=0))

    def fit(u, r, w):
        cd = make_cd()
        cd.bounds = (lo, hi)
        return cd.fit(u, r, w)

    reference = fit(u_new, r_new, None)
    rmse_ref = rmse(reference.predict(u_new), r_new)
    limit = stop_factor * max(rmse_ref, rmse_floor)
    u_all = np.vstack([u_orig, u_new])
    r_all = np.concatenate([r_orig, r_new])
    w_new = float(w_new_initial)
    accepted: tuple[CharacteristicDiagram, float, float, float] | None = None
    iterations: list[dict] = []
    for _ in range(max_iterations):
        w = np.concatenate([np.full(len(r_orig), float(w_orig)), np.full(len(r_new), w_new)])
        cd = fit(u_all, r_all, w)
        e_new = rmse(cd.predict(u_new), r_new)
        e_orig = rmse(cd.predict(u_orig), r_orig)
        iterations.append({"w_new": w_new, "rmse_new": e_new, "rmse_orig": e_orig})
        if e_new > limit:
            break
        accepted = (cd, w_new, e_new, e_orig)
        w_new *= decay
    if accepted is None:
        return LoadCaseUpdate(reference, math.inf, rmse_ref, rmse_ref,
                              rmse(reference.predict(u_orig), r_orig), False, iterations)
    cd, w_acc, e_new, e_orig = accepted
    return LoadCaseUpdate(cd, w_acc, rmse_ref, e_new, e_orig, True, iterations)
