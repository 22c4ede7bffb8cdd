"""Many ARX candidates at once: one regression matrix, batched WLS, stability and simulation.

Order selection (:mod:`talc_model.arx.order_selection`) fits and simulates every order combination
(n_a, n_b,1 .. n_b,r). Done one candidate at a time that is a regression matrix, an SVD, a
polynomial root finder and a filter per candidate, ~0.5 ms each of mostly Python overhead.
Here the work is shared:

- For a fixed n_a, every candidate's regression matrix is a column subset of the matrix of the
  largest orders (n_a, n_b,max, .. n_b,max), and its rows are the same (a row is dropped for a
  missing output, lagged outputs depend on n_a only, the inputs are complete). One QR
  decomposition A = Q R of the sqrt(W)-weighted largest matrix gives every candidate's
  problem min |A_S theta - b| as the small problem min |R_S theta - Q^T b| (A_S = Q R_S with
  orthonormal Q: same minimiser and the same singular values, hence the same rank).
- The small problems are solved by a stacked QR over all candidates with the same number of
  parameters (small groups of different sizes pooled into one stack with padding columns).
  The full-rank verdict is the one of ``numpy.linalg.lstsq`` / ``matrix_rank`` in
  :func:`talc_model.arx.model.solve_wls` (smallest singular value > eps * max(rows, parameters) *
  largest): decided from rigorous condition-number bounds of the triangular factor where they
  clear that tolerance by a wide margin, by an SVD otherwise (see :func:`_solve_small`).
- Stability: the pole of n_a = 1 is -a1 (exact); for n_a >= 2 the companion matrices are
  stacked and their eigenvalues taken at once (what ``numpy.roots`` does for one polynomial).
- Simulation mode: the input part B(q) u (+ c) of all candidates is one matrix product of the
  input-lag matrix with the stacked B coefficients; the autoregressive recursion then runs once
  over time with all candidates as a vector (summed in the order of ``scipy.signal.lfilter``'s
  transposed direct form), measured outputs replacing predictions where asked (state update).
  A handful of candidates over many steps in pure simulation (a coordinate-search sweep) is
  filtered one by one with ``scipy.signal.lfilter`` instead, which is faster there.

Nothing here imports rclpy; :mod:`talc_model.arx.order_selection` is the user.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from talc_model.arx.model import ArxOrders, as_finite_input_matrix, regression_matrix


class SharedRegression:
    """The weighted regression of the largest orders for one n_a, factorised once.

    Rows k in [``start``, ``stop``) with a finite output, finite lagged outputs and a weight
    > 0 enter (as in :func:`talc_model.arx.model.fit_arx`). Columns: -y[k-1] .. -y[k-na], then for
    each input j the lags nk .. nk + nb_max - 1, then the intercept.
    """

    def __init__(self, y: np.ndarray, u: np.ndarray, na: int, nb_max: int, nk: int, intercept: bool,
                 weights: np.ndarray | None, start: int, stop: int):
        y = np.asarray(y, dtype=float)
        u = as_finite_input_matrix(u)
        self.na = int(na)
        self.nb_max = int(nb_max)
        self.n_inputs = u.shape[1]
        self.intercept = bool(intercept)
        largest = ArxOrders(self.na, (self.nb_max,) * self.n_inputs, nk, intercept)
        phi, target, rows = regression_matrix(y, u, largest, start)
        w = np.ones(y.shape[0]) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != y.shape:
            raise ValueError(f"weights: shape {w.shape}, expected {y.shape}")
        w = np.where(rows < stop, w[rows], 0.0)
        ok = np.isfinite(target) & np.all(np.isfinite(phi), axis=1) & (w > 0)
        sw = np.sqrt(w[ok])
        a = phi[ok] * sw[:, None]
        b = target[ok] * sw
        self.n_rows = a.shape[0]
        self.n_columns = a.shape[1]
        if self.n_rows and self.n_columns:
            q, self.r = np.linalg.qr(a)              # reduced: r is min(rows, cols) x cols
            self.qtb = q.T @ b
        else:
            self.r = np.zeros((0, self.n_columns))
            self.qtb = np.zeros(0)

    def columns(self, nb: tuple[int, ...]) -> list[int]:
        """Column indices (in theta order) of the candidate (self.na, nb)."""
        cols = list(range(self.na))
        for j, n in enumerate(nb):
            base = self.na + j * self.nb_max
            cols.extend(range(base, base + n))
        if self.intercept:
            cols.append(self.n_columns - 1)
        return cols

    def _column_mask(self, nbs: np.ndarray) -> np.ndarray:
        """M x n_columns: which columns each candidate (row of ``nbs``) uses (as :meth:`columns`)."""
        mask = np.ones((nbs.shape[0], self.n_columns), dtype=bool)
        lags = np.arange(self.nb_max)
        for j in range(self.n_inputs):
            base = self.na + j * self.nb_max
            mask[:, base:base + self.nb_max] = lags[None, :] < nbs[:, j:j + 1]
        return mask

    def fit(self, nbs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fit the candidates ``nbs`` (M x n_inputs); return (theta, full_rank).

        ``theta`` is M x n_columns with the candidate's coefficients in its own columns and
        zeros elsewhere (undefined for rank-deficient candidates), ``full_rank`` is the verdict
        of :func:`talc_model.arx.model.solve_wls` (enough rows and rank = parameters).
        """
        nbs = np.asarray(nbs, dtype=int)
        if nbs.ndim != 2 or nbs.shape[1] != self.n_inputs:
            raise ValueError(f"nbs: shape {nbs.shape}, expected (candidates, {self.n_inputs})")
        m = nbs.shape[0]
        theta = np.zeros((m, self.n_columns))
        full_rank = np.zeros(m, dtype=bool)
        n_params = self.na + nbs.sum(axis=1) + int(self.intercept)
        fittable = (n_params > 0) & (n_params <= self.n_rows)     # else: nothing to fit / too few rows
        sizes, counts = np.unique(n_params[fittable], return_counts=True)
        pooled = []
        for p, count in zip(sizes, counts):
            sel = np.flatnonzero(fittable & (n_params == p))
            if count < POOL_BELOW:
                pooled.append(sel)
                continue
            idx = np.nonzero(self._column_mask(nbs[sel]))[1].reshape(sel.size, p)   # (M_p, p)
            k = idx.max() + 1                                                # rows below are 0
            sub = np.moveaxis(self.r[:k, idx], 1, 0)                         # (M_p, K, p)
            th, ok = _solve_small(sub, self.qtb[:k], self.n_rows)
            theta[np.repeat(sel, p), idx.ravel()] = th.ravel()
            full_rank[sel] = ok
        if pooled:
            # small groups of different sizes: one padded stack (see _solve_small)
            sel = np.concatenate(pooled)
            mask = self._column_mask(nbs[sel])
            p_each = mask.sum(axis=1)
            p_max = int(p_each.max())
            rows, cols = np.nonzero(mask)
            pos = (np.cumsum(mask, axis=1) - 1)[rows, cols]
            r_top = self.r[: int(cols.max()) + 1]                         # rows below are 0
            r_ext = np.concatenate([r_top, np.zeros((r_top.shape[0], 1))], axis=1)  # + a zero column
            idx = np.full((sel.size, p_max), r_ext.shape[1] - 1)
            idx[rows, pos] = cols
            pad = np.arange(p_max)[None, :] >= p_each[:, None]              # (M, p_max)
            sub = np.concatenate([np.moveaxis(r_ext[:, idx], 1, 0),
                                  pad[:, :, None] * np.eye(p_max)[None, :, :]], axis=1)
            qtb = np.concatenate([self.qtb[: r_top.shape[0]], np.zeros(p_max)])
            th, ok = _solve_small(sub, qtb, self.n_rows, p_each)
            theta[sel[rows], cols] = th[rows, pos]
            full_rank[sel] = ok
        return theta, full_rank


#: how far (factor) the condition-number bounds of :func:`_solve_small` must clear lstsq's
#: rank tolerance to decide without an SVD
RANK_DECISION_MARGIN = 100.0


#: groups of candidates with the same number of parameters smaller than this are pooled
#: into one padded stack (a coordinate-search sweep has ~10 candidates of 10 sizes)
POOL_BELOW = 8


def _solve_small(sub: np.ndarray, qtb: np.ndarray, n_rows: int,
                 p_each: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Least squares min |sub[m] theta - qtb| for a stack of K x p matrices; (theta, full rank).

    Full rank means what ``numpy.linalg.lstsq`` (and ``matrix_rank``) on the n_rows x p
    matrix decides: smallest singular value > eps * max(n_rows, p) * largest. A stacked QR
    (of [sub | qtb], so Q^T qtb comes without forming Q) gives sub = Q T (T p x p upper
    triangular, the same singular values); the condition
    number lies in [max|T_ii| / min|T_ii|, |T|_F |T^-1|_F] and in [|T|_F |T^-1|_F / p, ..];
    candidates whose bounds clear the tolerance by :data:`RANK_DECISION_MARGIN` are decided
    from them (theta = T^-1 Q^T qtb), the others by an SVD as lstsq does it.

    ``p_each``: candidate m uses only its first p_each[m] columns; the others are padding,
    zero in the K rows of the problem and a unit vector in an extra row of their own (so
    they are orthogonal to the real columns and to each other: T is block diagonal with an
    identity block, the real block and its solution are those of the unpadded problem).
    """
    m, _, p_max = sub.shape
    p_each = np.full(m, p_max) if p_each is None else np.asarray(p_each)
    real = np.arange(p_max)[None, :] < p_each[:, None]                   # (M, p_max)
    real2 = real[:, :, None] & real[:, None, :]
    eps = np.finfo(float).eps
    limit = 1.0 / (eps * np.maximum(n_rows, p_each))        # largest admissible condition
    theta = np.zeros((m, p_max))
    full = np.zeros(m, dtype=bool)
    # QR of [sub | qtb] without forming Q: R = [[T, Q^T qtb], [0, residual]]
    aug = np.concatenate([sub, np.broadcast_to(qtb[None, :, None], (m, qtb.size, 1))], axis=2)
    r_aug = np.linalg.qr(aug, mode="r")
    t = r_aug[:, :p_max, :p_max]
    qtb_t_all = r_aug[:, :p_max, p_max]
    diag = np.abs(np.diagonal(t, axis1=1, axis2=2))
    dmin = np.where(real, diag, np.inf).min(axis=1)
    dmax = np.where(real, diag, 0.0).max(axis=1)
    undecided = ~(dmin * limit * RANK_DECISION_MARGIN <= dmax)    # else surely deficient
    inv_idx = np.flatnonzero(undecided)
    if inv_idx.size:
        with np.errstate(over="ignore", invalid="ignore"):
            t_inv = np.linalg.inv(t[inv_idx])
            r2 = real2[inv_idx]
            bound = (np.linalg.norm(np.where(r2, t[inv_idx], 0.0), axis=(1, 2))
                     * np.linalg.norm(np.where(r2, t_inv, 0.0), axis=(1, 2)))
        lim = limit[inv_idx]
        sure_full = bound * RANK_DECISION_MARGIN < lim
        sure_deficient = bound > lim * RANK_DECISION_MARGIN * p_each[inv_idx]
        good = inv_idx[sure_full]
        theta[good] = np.einsum("mpq,mq->mp", t_inv[sure_full], qtb_t_all[good])
        full[good] = True
        undecided[inv_idx[sure_full | sure_deficient]] = False
    for i in np.flatnonzero(undecided):                     # rare: near lstsq's tolerance
        p = int(p_each[i])
        a = sub[i, :, :p]
        uu, s, vt = np.linalg.svd(a, full_matrices=False)
        full[i] = bool(np.all(s > eps * max(n_rows, p) * s[0]))
        s_safe = np.where(s > 0, s, 1.0)
        theta[i, :p] = vt.T @ ((uu.T @ qtb) / s_safe)
    return theta, full


def input_lag_matrix(u: np.ndarray, nb_max: int, nk: int, intercept: bool, first: int) -> np.ndarray:
    """Rows k = first .. N-1 of [u_1[k-nk] .. u_1[k-nk-nb_max+1], u_2[..] .., 1]: the input
    columns of :class:`SharedRegression` (``first`` must be >= nk + nb_max - 1)."""
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    orders = ArxOrders(0, (nb_max,) * u.shape[1], nk, intercept)
    if first < orders.max_lag:
        raise ValueError(f"input_lag_matrix: first row {first} is before the largest input lag {orders.max_lag}")
    phi, _, _ = regression_matrix(np.zeros(u.shape[0]), u, orders, first)
    return phi


def poles_inside(a: np.ndarray, margin: float = 0.0, real_positive: bool = False) -> np.ndarray:
    """Per row of ``a`` (M x n_a: a1 .. a_na): are all poles of 1/A(q) inside radius 1 - margin
    (and real and > 0 with ``real_positive``)? Same test as :meth:`ArxModel.is_stable`."""
    a = np.asarray(a, dtype=float)
    m, na = a.shape
    if na == 0:
        return np.ones(m, dtype=bool)
    if na == 1:
        p = -a[:, 0]
        ok = np.abs(p) < 1.0 - margin
        if real_positive:
            ok &= p > 0
        return ok
    comp = np.zeros((m, na, na))
    comp[:, 0, :] = -a
    comp[:, np.arange(1, na), np.arange(na - 1)] = 1.0
    p = np.linalg.eigvals(comp).astype(complex)
    ok = np.all(np.abs(p) < 1.0 - margin, axis=1)
    if real_positive:
        ok &= np.all((np.abs(p.imag) <= 1e-6) & (p.real > 0), axis=1)
    return ok


#: a pure simulation filters each candidate with ``scipy.signal.lfilter`` (~25 us) instead
#: of running the vectorised time loop (~1-2 us per step and unit of n_a, nearly independent
#: of the number of candidates) when candidates * LFILTER_STEPS < steps * n_a; measured on
#: the 2-core development machine
LFILTER_STEPS = 25


def simulate_batch(a: np.ndarray, bu: np.ndarray, y_before: np.ndarray,
                   replace: np.ndarray | None = None, y_replace: np.ndarray | None = None) -> np.ndarray:
    """Simulation-mode predictions of M candidates over T steps.

    ``a`` (M x n_a), ``bu`` (T x M) the input parts B(q) u (+ c) at the T steps, ``y_before``
    the n_a outputs before the first step (oldest first). Predictions are fed back; where
    ``replace[t]`` is true, ``y_replace[t]`` replaces the prediction in the fed-back history
    after it has been recorded (the TALC state update, as in :meth:`ArxModel.simulate`).
    Returns T x M predictions.
    """
    a = np.asarray(a, dtype=float)
    bu = np.asarray(bu, dtype=float)
    m, na = a.shape
    t_len = bu.shape[0]
    if na == 0:
        return bu.copy()
    y_before = np.asarray(y_before, dtype=float)
    if y_before.shape != (na,):
        raise ValueError(f"simulate_batch: y_before has shape {y_before.shape}, expected ({na},)")
    pred = np.empty((t_len, m))
    hist = np.empty((na + t_len, m))        # hist[na + t] = fed-back output of step t
    hist[:na] = y_before[:, None]
    at = np.ascontiguousarray(a.T)          # at[i] = a_{i+1} of every candidate
    rep = np.zeros(t_len, dtype=bool) if replace is None else np.asarray(replace, dtype=bool)
    if not np.any(rep) and m * LFILTER_STEPS < t_len * na:
        # few candidates, many steps (a coordinate-search sweep): a C filter each is faster.
        # Initial state of the transposed direct form for y_before (what lfiltic computes):
        # zi[j] = -(a_{j+1} y[-1] + a_{j+2} y[-2] + .. + a_na y[-(na-j)])
        y_rev = y_before[::-1]
        zi = np.array([[-np.dot(a[i, j:], y_rev[: na - j]) for j in range(na)] for i in range(m)])
        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(m):
                pred[:, i], _ = signal.lfilter([1.0], np.concatenate(([1.0], a[i])), bu[:, i], zi=zi[i])
        return pred
    with np.errstate(over="ignore", invalid="ignore"):   # unstable candidates may overflow
        if na == 1:
            a1 = at[0]
            h = hist[0].copy()
            for t in range(t_len):
                h = bu[t] - a1 * h
                pred[t] = h
                if rep[t]:
                    h = np.full(m, y_replace[t])
            return pred
        for t in range(t_len):
            # lfilter's order: x + (-a1 y[t-1] + (-a2 y[t-2] + ... ))
            acc = at[na - 1] * hist[t]
            for i in range(na - 1, 0, -1):
                acc = at[i - 1] * hist[na + t - i] + acc
            pred[t] = bu[t] - acc
            hist[na + t] = y_replace[t] if rep[t] else pred[t]
    return pred
