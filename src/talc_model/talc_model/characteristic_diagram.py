"""Characteristic diagrams (CD): smoothed grid regression, load-case update, input selection.

Spec: ``shared/spec/characteristic-diagrams.md`` (Priber's smoothed grid regression as used by
Naumann, Ihlenfeldt, Putz et al.). The papers describe the CD only in words; this module
implements the reconstruction of the digest (§1.2), with every choice a parameter:

* **Grid:** equidistant knots per input over the training range (or given ``bounds``),
  ``n_intervals[d]`` intervals, tensor-product piecewise multilinear ("hat") kernels, so one
  evaluation touches only 2^D vertices.
* **Fit:** weighted least squares on the data equations plus smoothing equations (second
  differences of the vertex coefficients along every input) and a tiny ridge that pins the
  null space of the smoothing operator. The smoothing weight ``smoothing`` is dimensionless:
  the data term is the weighted *mean* squared error and the smoothing term the mean squared
  second derivative in inputs scaled to [0, 1] (choice of ours; the papers give no values).
  ``smoothing[d] = 0`` removes the smoothing equations of a discrete input [003 §3].
* **Outside the grid:** inputs are clamped to the grid (constant extrapolation) and counted in
  :attr:`CharacteristicDiagram.out_of_range_count` (the papers stress that extrapolation is poor).
* **Load-case update** (:func:`load_case_update`, [002 §3.2]): an additive update CD fitted to
  the base model's residuals on the new load case, with the original data's residuals as
  anchors and the weight-decay loop w_new = 10 -> *0.7 until RMSE_new_i > 2 RMSE_ref.
* **Input selection** [003 §4]: forward heuristic (:func:`forward_selection`) and the stability
  index (:func:`stability_index`, :func:`stability_selection`).
* **Update from measurements** (:func:`measurement_update`, [002 §3.2] production case): per
  sample a temporary geometric CD through the base model's support-point values and the
  measured points (weights 1 : 10), then one temperature-input update CD per support point.

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
from scipy.spatial.distance import pdist
from thermal_comp_common.metrics import rmse


class CharacteristicDiagramError(ValueError):
    """Bad input to a characteristic diagram; the message names the argument and value."""


def _as_2d(u, name: str) -> np.ndarray:
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
class CharacteristicDiagram:
    """A smoothed-grid-regression characteristic diagram y = f(u), u in R^D.

    Parameters
    ----------
    n_intervals: grid intervals per input (int or one per input); vertices = n + 1 per input.
    smoothing: dimensionless smoothing weight lambda (scalar or one per input; 0 = none).
    ridge: tiny Tikhonov weight relative to the data term, pins the smoothing null space.
    bounds: optional (lower, upper) arrays of the grid domain; default the training range.
    """

    n_intervals: int | Sequence[int] = 4
    smoothing: float | Sequence[float] = 1e-4
    ridge: float = 1e-9
    bounds: tuple[Sequence[float], Sequence[float]] | None = None
    # fitted state
    lower_: np.ndarray | None = field(default=None, repr=False)
    upper_: np.ndarray | None = field(default=None, repr=False)
    shape_: tuple[int, ...] | None = field(default=None, repr=False)
    coef_: np.ndarray | None = field(default=None, repr=False)
    out_of_range_count: int = 0

    # ---------------------------------------------------------------- geometry
    @property
    def n_inputs(self) -> int:
        if self.shape_ is None:
            raise CharacteristicDiagramError("characteristic diagram is not fitted")
        return len(self.shape_)

    def _cells(self, u: np.ndarray, count_out_of_range: bool = True):
        """Cell index and local coordinate tau in [0,1] per sample and input (clamped)."""
        lo, hi = self.lower_, self.upper_
        n = np.asarray(self.shape_) - 1
        s = (u - lo) / (hi - lo) * n
        outside = (s < -1e-9) | (s > n + 1e-9)
        if count_out_of_range:
            self.out_of_range_count += int(np.any(outside, axis=1).sum())
        s = np.clip(s, 0.0, n)
        idx = np.minimum(np.floor(s).astype(int), n - 1)
        tau = s - idx
        return idx, tau

    def basis_matrix(self, u, count_out_of_range: bool = False) -> sp.csr_matrix:
        """Sparse K x N matrix of the kernel values Phi_v(u_k) (<= 2^D non-zeros per row)."""
        u = _as_2d(u, "u")
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
    def fit(self, u, y, weights=None) -> "CharacteristicDiagram":
        """Fit the vertex coefficients by weighted, smoothed least squares (R3-R6 of the digest)."""
        u = _as_2d(u, "u")
        y = np.asarray(y, dtype=float).ravel()
        if y.shape[0] != u.shape[0]:
            raise CharacteristicDiagramError(f"y: {y.shape[0]} values for {u.shape[0]} samples")
        w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=float).ravel()
        if w.shape != y.shape:
            raise CharacteristicDiagramError(f"weights: {w.shape[0]} values for {y.shape[0]} samples")
        if np.any(w < 0) or not np.all(np.isfinite(w)):
            raise CharacteristicDiagramError("weights: must be finite and >= 0")
        finite = np.all(np.isfinite(u), axis=1) & np.isfinite(y)
        if not finite.any():
            raise CharacteristicDiagramError("u/y: no sample with finite inputs and output")
        u, y, w = u[finite], y[finite], w[finite]
        if w.sum() <= 0:
            raise CharacteristicDiagramError("weights: all zero")
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
        self.out_of_range_count = 0
        return self

    def predict(self, u) -> np.ndarray:
        """Evaluate the diagram; inputs outside the grid are clamped (and counted)."""
        if self.coef_ is None:
            raise CharacteristicDiagramError("characteristic diagram is not fitted")
        u = _as_2d(u, "u")
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
                "coef": self.coef_.tolist()}

    @classmethod
    def from_state(cls, state: dict) -> "CharacteristicDiagram":
        try:
            cd = cls(n_intervals=list(state["n_intervals"]), smoothing=state["smoothing"],
                     ridge=float(state["ridge"]))
            cd.lower_ = np.asarray(state["lower"], dtype=float)
            cd.upper_ = np.asarray(state["upper"], dtype=float)
            cd.shape_ = tuple(int(v) + 1 for v in state["n_intervals"])
            cd.coef_ = np.asarray(state["coef"], dtype=float)
        except KeyError as exc:
            raise CharacteristicDiagramError(f"characteristic diagram state: missing key {exc}") from None
        if cd.coef_.size != int(np.prod(cd.shape_)):
            raise CharacteristicDiagramError(f"characteristic diagram state: 'coef' has {cd.coef_.size} "
                                             f"values, grid has {int(np.prod(cd.shape_))} vertices")
        return cd


def fit_with_grid_refinement(u, y, u_val, y_val, *, start_intervals: int = 1, max_intervals: int = 32,
                             min_relative_gain: float = 0.05, weights=None,
                             smoothing: float | Sequence[float] = 1e-4) -> tuple[CharacteristicDiagram, list[dict]]:
    """[002 §3.2]: start coarse and equidistant, halve the grid elements until the validation
    RMSE improves by less than ``min_relative_gain`` (the paper's "no significant improvement";
    the threshold is our choice). Returns the best diagram and the refinement history."""
    history: list[dict] = []
    best: CharacteristicDiagram | None = None
    best_err = math.inf
    n = int(start_intervals)
    while n <= max_intervals:
        cd = CharacteristicDiagram(n_intervals=n, smoothing=smoothing).fit(u, y, weights)
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
    u_orig, u_new = _as_2d(u_orig, "u_orig"), _as_2d(u_new, "u_new")
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


# ---------------------------------------------------------------------------------------
# Input-variable selection [003 §4]

@dataclass
class SelectionStep:
    subset: tuple[int, ...]
    score: float


def _holdout_split(k: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    perm = rng.permutation(k)
    n_test = max(1, int(round(test_fraction * k)))
    return perm[n_test:], perm[:n_test]


def forward_selection(m, y, *, max_inputs: int = 4, make_cd: Callable[[], CharacteristicDiagram] | None = None,
                      test_fraction: float = 0.2, seed: int = 0,
                      min_relative_gain: float = 0.0) -> list[SelectionStep]:
    """Sequential forward heuristic (variant 1 of [003 §4]).

    At each size L every free candidate is added to the previous best subset, a CD with the
    same settings is fitted and scored; the best becomes S_L. The paper leaves the norm and
    "tested using training data" open; we score by the RMSE on a fixed random hold-out part
    of the data (``test_fraction``, ``seed``), which penalises over-fitting grids. Stops early
    when the best score improves by less than ``min_relative_gain``.
    Returns the best subset (column indices) and its score for each size.
    """
    m = _as_2d(m, "m")
    y = np.asarray(y, dtype=float).ravel()
    if y.shape[0] != m.shape[0]:
        raise CharacteristicDiagramError(f"y: {y.shape[0]} values for {m.shape[0]} samples")
    make_cd = make_cd or (lambda: CharacteristicDiagram(n_intervals=4, smoothing=1e-4))
    train, test = _holdout_split(m.shape[0], test_fraction, seed)
    chosen: list[int] = []
    steps: list[SelectionStep] = []
    for _ in range(min(max_inputs, m.shape[1])):
        best: SelectionStep | None = None
        for p in range(m.shape[1]):
            if p in chosen:
                continue
            cols = chosen + [p]
            cd = make_cd().fit(m[np.ix_(train, cols)], y[train])
            score = rmse(cd.predict(m[np.ix_(test, cols)]), y[test])
            if best is None or score < best.score:
                best = SelectionStep(tuple(cols), score)
        assert best is not None
        if steps and not best.score < steps[-1].score * (1.0 - min_relative_gain):
            break
        steps.append(best)
        chosen = list(best.subset)
    return steps


class StabilityIndex:
    """The stability analysis of [003 §4 (d)] over a candidate matrix M (K x P) and output y.

    Columns are normalised to [0, 1]; for every pair of samples (a, b) the per-variable input
    distance |m_a - m_b| and the output distance |y_a - y_b| are kept (pairs in chunks of the
    ``scipy.spatial.distance.pdist`` order). For a subset S:

    * ``variant="printed"`` (eq. 3 as printed): i^S = sum (1 - prod_{p in S} |dm_p|) |dy|;
    * ``variant="closeness"`` (default): i^S = sum prod_{p in S} (1 - |dm_p|) |dy|, i.e. a pair
      counts as close only when it is close in *every* selected input - what the paper's prose
      says the product should describe. Both are lower-is-better and comparable only between
      subsets of the same size (the benchmark measures how often each finds the true inputs).

    ``max_samples`` subsamples the rows (fixed seed) to bound the K^2/2 pair memory.
    """

    def __init__(self, m, y, *, variant: str = "closeness", max_samples: int = 400, seed: int = 0):
        if variant not in ("closeness", "printed"):
            raise CharacteristicDiagramError(f"variant: must be 'closeness' or 'printed', got {variant!r}")
        m = _as_2d(m, "m")
        y = np.asarray(y, dtype=float).ravel()
        if y.shape[0] != m.shape[0]:
            raise CharacteristicDiagramError(f"y: {y.shape[0]} values for {m.shape[0]} samples")
        ok = np.all(np.isfinite(m), axis=1) & np.isfinite(y)
        m, y = m[ok], y[ok]
        if m.shape[0] < 3:
            raise CharacteristicDiagramError(f"m: stability analysis needs >= 3 finite samples, got {m.shape[0]}")
        if m.shape[0] > max_samples:
            keep = np.sort(np.random.default_rng(seed).choice(m.shape[0], max_samples, replace=False))
            m, y = m[keep], y[keep]
        span = m.max(axis=0) - m.min(axis=0)
        mn = (m - m.min(axis=0)) / np.where(span > 0, span, 1.0)
        self.variant = variant
        self.n_candidates = m.shape[1]
        self.dy = pdist(y[:, None], "cityblock").astype(np.float32)
        dm = np.stack([pdist(mn[:, [p]], "cityblock") for p in range(m.shape[1])]).astype(np.float32)
        # factor per variable whose product over S gives the pair weight
        self.factor = dm if variant == "printed" else (1.0 - dm)

    def index(self, subset: Sequence[int]) -> float:
        prod = np.prod(self.factor[list(subset)], axis=0)
        weight = (1.0 - prod) if self.variant == "printed" else prod
        return float(weight @ self.dy)

    def best_of_size(self, size: int, candidates: Sequence[Sequence[int]] | None = None) -> SelectionStep:
        subsets = candidates if candidates is not None else itertools.combinations(range(self.n_candidates), size)
        best: SelectionStep | None = None
        for s in subsets:
            score = self.index(s)
            if best is None or score < best.score:
                best = SelectionStep(tuple(sorted(s)), score)
        if best is None:
            raise CharacteristicDiagramError(f"size: no candidate subset of size {size}")
        return best


def stability_index(m, y, subset: Sequence[int], variant: str = "closeness") -> float:
    """The instability index i^S of one subset (lower = more suitable); see :class:`StabilityIndex`."""
    return StabilityIndex(m, y, variant=variant).index(subset)


def stability_selection(m, y, *, max_inputs: int = 4, exhaustive_up_to: int = 3, variant: str = "closeness",
                        max_samples: int = 400, seed: int = 0) -> list[SelectionStep]:
    """Best subset per size by the stability index, searched as in [003 §5]: all combinations
    up to ``exhaustive_up_to`` inputs, then from the previous optimum remove one variable and
    add two (the removed one may come back: the paper does not forbid it). The index is
    comparable only within one size; choose the size by CD test error."""
    si = StabilityIndex(m, y, variant=variant, max_samples=max_samples, seed=seed)
    p = si.n_candidates
    steps: list[SelectionStep] = []
    for size in range(1, min(max_inputs, p) + 1):
        if size <= exhaustive_up_to or not steps:
            steps.append(si.best_of_size(size))
            continue
        prev = steps[-1].subset
        cands = set()
        for drop in prev:
            kept = [v for v in prev if v != drop]
            free = [v for v in range(p) if v not in kept]
            for pair in itertools.combinations(free, 2):
                cands.add(tuple(sorted(kept + list(pair))))
        steps.append(si.best_of_size(size, sorted(cands)))
    return steps


# ---------------------------------------------------------------------------------------
# Load-case update from measurement data [002 §3.2, digest §2.3]

@dataclass
class MeasurementUpdate:
    """Update CDs per support point (temperature inputs) from measured relative displacements.

    ``predict(temperatures)`` gives the additive correction of every support point, shape
    (samples, support points); the base model's support-point values plus this are the updated
    ones, which the usual geometric interpolation then carries to the TCP.
    """

    inputs: list[int]                          # temperature columns the update CDs use
    cds: list[CharacteristicDiagram]           # one per support point
    adjusted: np.ndarray                       # (samples, support points) after step C
    rmse_before: float                         # base model vs measurements at the measured points
    rmse_after: float                          # updated model vs measurements (training data)

    def predict(self, temperatures) -> np.ndarray:
        t = _as_2d(temperatures, "temperatures")[:, self.inputs]
        return np.column_stack([cd.predict(t) for cd in self.cds])


def geometric_diagram(support_xyz, support_values, measured_xyz, measured_values, *,
                      w_support: float = 1.0, w_measured: float = 10.0, n_intervals: int = 2,
                      smoothing: float = 1e-3) -> CharacteristicDiagram:
    """Step B of [002 §3.2]: a temporary 3-D CD g(X, Y, Z) through the predicted support-point
    values (weight ``w_support``) and the measured displacements (weight ``w_measured``; 10:1 in
    the paper's Fig. 3 example). The grid spans the support points (the workspace)."""
    sp = _as_2d(support_xyz, "support_xyz")
    mp = _as_2d(measured_xyz, "measured_xyz")
    if sp.shape[1] != mp.shape[1]:
        raise CharacteristicDiagramError(f"measured_xyz: {mp.shape[1]} coordinates, support_xyz has {sp.shape[1]}")
    u = np.vstack([sp, mp])
    y = np.concatenate([np.ravel(support_values), np.ravel(measured_values)])
    w = np.concatenate([np.full(sp.shape[0], float(w_support)), np.full(mp.shape[0], float(w_measured))])
    both = np.vstack([sp, mp])
    cd = CharacteristicDiagram(n_intervals=n_intervals, smoothing=smoothing,
                               bounds=(both.min(axis=0), both.max(axis=0)))
    return cd.fit(u, y, w)


def measurement_update(temperatures, base_support, support_xyz, measured_xyz, measured, *,
                       inputs: Sequence[int] | None = None, w_support: float = 1.0, w_measured: float = 10.0,
                       geometric_intervals: int = 2, geometric_smoothing: float = 1e-3,
                       make_cd: Callable[[], CharacteristicDiagram] | None = None,
                       augment_noise_k: float = 0.0, augment_copies: int = 0, seed: int = 0) -> MeasurementUpdate:
    """The measurement-based load-case update of [002 §3.2] for one displacement component.

    ``temperatures`` (K samples x P sensors); ``base_support`` (K x J) the base model's relative
    errors at the J support points for each sample (step A); ``measured`` (K x M) the relative
    displacements measured at ``measured_xyz`` (M x 3) - with active compensation, add the
    applied compensation back first (digest gap 4). Step B/C: per sample a geometric CD through
    support predictions and measurements gives adjusted support values; step D: per support
    point an update CD on the temperatures ``inputs`` (default all; choose them with
    :func:`forward_selection` / :func:`stability_selection`) fitted to adjusted - predicted.
    ``augment_copies`` noisy copies of the temperatures (std ``augment_noise_k``) make the
    update robust to run-to-run scatter, as the paper suggests (±1 K in its repeat runs).
    """
    temps = _as_2d(temperatures, "temperatures")
    base = _as_2d(base_support, "base_support")
    meas = _as_2d(measured, "measured")
    sp, mp = _as_2d(support_xyz, "support_xyz"), _as_2d(measured_xyz, "measured_xyz")
    k = temps.shape[0]
    if base.shape != (k, sp.shape[0]):
        raise CharacteristicDiagramError(f"base_support: shape {base.shape}, expected ({k}, {sp.shape[0]})")
    if meas.shape != (k, mp.shape[0]):
        raise CharacteristicDiagramError(f"measured: shape {meas.shape}, expected ({k}, {mp.shape[0]})")
    cols = list(range(temps.shape[1])) if inputs is None else list(inputs)
    make_cd = make_cd or (lambda: CharacteristicDiagram(n_intervals=2, smoothing=1e-3))
    adjusted = np.empty_like(base)
    for i in range(k):
        g = geometric_diagram(sp, base[i], mp, meas[i], w_support=w_support, w_measured=w_measured,
                              n_intervals=geometric_intervals, smoothing=geometric_smoothing)
        adjusted[i] = g.predict(sp)
    delta = adjusted - base
    t_fit, d_fit = temps[:, cols], delta
    if augment_copies > 0 and augment_noise_k > 0:
        rng = np.random.default_rng(seed)
        t_fit = np.vstack([t_fit] + [t_fit + rng.normal(0, augment_noise_k, t_fit.shape)
                                     for _ in range(augment_copies)])
        d_fit = np.vstack([d_fit] * (augment_copies + 1))
    cds = [make_cd().fit(t_fit, d_fit[:, j]) for j in range(sp.shape[0])]
    update = MeasurementUpdate(cols, cds, adjusted, math.nan, math.nan)
    # quality at the measured points: the support values carried to the measured points by a
    # geometric CD through the support points only (multilinear on a 3x3x3 lattice; the papers
    # interpolate quadratically), base vs updated
    err_b, err_a = [], []
    corr = update.predict(temps)
    for i in range(k):
        gb = geometric_diagram(sp, base[i], mp[:0], meas[i][:0], n_intervals=geometric_intervals,
                               smoothing=geometric_smoothing)
        ga = geometric_diagram(sp, base[i] + corr[i], mp[:0], meas[i][:0], n_intervals=geometric_intervals,
                               smoothing=geometric_smoothing)
        err_b.append(gb.predict(mp) - meas[i])
        err_a.append(ga.predict(mp) - meas[i])
    update.rmse_before = rmse(np.concatenate(err_b), 0.0)
    update.rmse_after = rmse(np.concatenate(err_a), 0.0)
    return update
