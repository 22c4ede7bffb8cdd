"""The batched order selection gives the per-candidate selection's answers.

Every candidate's verdict (rank, stability) and score of the batched scorer is compared with
the per-candidate reference (one fit_arx + ArxModel.simulate each, the implementation before
the batched one), and select_orders with _select_orders_reference, on random ARX systems with
weights, missing outputs, measured masks, state updates, intercepts and several n_a ranges,
and on rank-deficient data (constant and collinear inputs, too few rows).
"""
import itertools
import math

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders, RankDeficientError, fit_arx
from talc_model.arx.batch import SharedRegression, input_lag_matrix, poles_inside, simulate_batch
from talc_model.arx.order_selection import (_BatchedScorer, _PerCandidateScorer, _scoring_problem,
                                        _select_orders_reference, select_orders)

REL = 1e-9


def _random_system(seed: int, n: int = 500, r: int = 3, noise: float = 0.02):
    """A random stable MISO ARX system (n_a 1 or 2, n_b 1..4) driven by held random steps."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, size=(n // 6 + 1, r)), 6, axis=0)[:n]
    u += 0.05 * rng.normal(size=u.shape)
    na = int(rng.integers(1, 3))
    poles = rng.uniform(0.5, 0.95, size=na)
    a = np.poly(poles)[1:]
    nb = tuple(int(v) for v in rng.integers(1, 5, size=r))
    b = rng.uniform(-0.5, 0.5, size=sum(nb))
    orders = ArxOrders(na, nb)
    m = ArxModel(orders, np.concatenate([a, b]))
    y = np.zeros(n)
    for k in range(orders.max_lag, n):
        y[k] = m.predict_one(y, u, k) + rng.normal(scale=noise)
    return y, u, rng


def _scenario(name: str, seed: int):
    """(y, u, select_orders keyword arguments) of a named test scenario."""
    y, u, rng = _random_system(seed)
    n = y.size
    measured = np.zeros(n, bool)
    measured[: n // 3] = True
    measured[n // 3::9] = True
    if name == "plain":
        return y, u, {}
    if name == "weighted":
        return y, u, {"weights": rng.uniform(0.1, 2.0, size=n)}
    if name == "missing_outputs":          # NaN outputs (also inside the training part)
        y = y.copy()
        y[rng.choice(n, size=n // 10, replace=False)] = np.nan
        return y, u, {}
    if name == "talc_like":                # sparse measurements, low weight on predictions
        w = np.where(measured, 1.0, 0.02)
        return y, u, {"weights": w, "measured": measured}
    if name == "state_updates":
        w = np.where(measured, 1.0, 0.02)
        return y, u, {"weights": w, "measured": measured, "state_updates": True}
    if name == "state_updates_nan":        # unmeasured outputs missing, TALC predictor scoring
        y = np.where(measured, y, np.nan)
        return y, u, {"measured": measured, "state_updates": True}
    if name == "intercept":
        return y + 0.7, u, {"intercept": True}
    if name == "bounded_poles":            # admissibility bounds reject some candidates
        return y, u, {"max_pole_radius": 0.95, "real_positive_poles": True}
    if name == "unstable_allowed":
        return y, u, {"require_stable": False, "criterion": "bic"}
    raise KeyError(name)


SCENARIOS = ["plain", "weighted", "missing_outputs", "talc_like", "state_updates",
             "state_updates_nan", "intercept", "bounded_poles", "unstable_allowed"]
NA_RANGES = [(0, 1), (1, 1), (1, 2)]


def _scorers(y, u, na_range, nb_range, kw):
    """Both scorers set up as select_orders sets them up, and every key of the grid."""
    problem = _scoring_problem(y, u, na_range, nb_range, **kw)
    keys = [(na, nb) for na in range(na_range[0], na_range[1] + 1)
            for nb in itertools.product(range(nb_range[0], nb_range[1] + 1), repeat=u.shape[1])]
    return _PerCandidateScorer(problem), _BatchedScorer(problem), keys


def _assert_same_scores(ref_scores, batch_scores):
    a, b = np.asarray(ref_scores), np.asarray(batch_scores)
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    fin = np.isfinite(a)
    np.testing.assert_allclose(b[fin], a[fin], rtol=REL, atol=0)


@pytest.mark.parametrize("na_range", NA_RANGES)
@pytest.mark.parametrize("name", SCENARIOS)
def test_every_candidate_scores_as_in_the_per_candidate_evaluation(name, na_range):
    y, u, kw = _scenario(name, seed=SCENARIOS.index(name))
    ref, batch, keys = _scorers(y, u, na_range, (1, 4), kw)
    ref_scores = ref.scores(keys)
    _assert_same_scores(ref_scores, batch.scores(keys))
    assert batch.deficient_keys == ref.deficient_keys
    if name != "unstable_allowed":
        assert np.isfinite(ref_scores).sum() > len(keys) // 4     # the comparison is not vacuous
    if name == "bounded_poles" and na_range[1] > 0:
        assert not np.isfinite(ref_scores).all()                   # the bound rejects some


@pytest.mark.parametrize("na_range", NA_RANGES)
@pytest.mark.parametrize("name", SCENARIOS)
def test_select_orders_returns_what_the_reference_returns(name, na_range):
    y, u, kw = _scenario(name, seed=10 + SCENARIOS.index(name))
    new = select_orders(y, u, na_range, (1, 4), **kw)
    old = _select_orders_reference(y, u, na_range, (1, 4), **kw)
    assert new.orders == old.orders
    assert new.score == pytest.approx(old.score, rel=REL)
    np.testing.assert_allclose(new.model.theta, old.model.theta, rtol=REL, atol=1e-12)
    assert new.validation_rms == pytest.approx(old.validation_rms, rel=REL)
    assert (new.candidates_tried, new.candidates_rank_deficient) == \
        (old.candidates_tried, old.candidates_rank_deficient)


@pytest.mark.parametrize("name", ["plain", "talc_like", "state_updates", "intercept"])
def test_coordinate_search_takes_the_same_steps(name):
    y, u, kw = _scenario(name, seed=20 + SCENARIOS.index(name))
    new = select_orders(y, u, (1, 2), (1, 6), exhaustive_limit=20, **kw)
    old = _select_orders_reference(y, u, (1, 2), (1, 6), exhaustive_limit=20, **kw)
    assert new.orders == old.orders
    assert new.candidates_tried == old.candidates_tried < 2 * 6 ** 3
    assert new.candidates_rank_deficient == old.candidates_rank_deficient
    assert new.score == pytest.approx(old.score, rel=REL)


def _rank_deficient_case(name: str):
    rng = np.random.default_rng(7)
    n = 300
    u = np.repeat(rng.uniform(-1, 1, size=(n // 5 + 1, 3)), 5, axis=0)[:n]
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.8 * y[k - 1] + 0.3 * u[k, 0] - 0.2 * u[k, 1] + rng.normal(scale=0.01)
    kw = {}
    if name == "constant_input_with_intercept":   # u_3 constant: collinear with the intercept
        u[:, 2] = 1.5
        kw["intercept"] = True
    elif name == "constant_input_lags":           # lags of a constant input are collinear
        u[:, 2] = 0.4
    elif name == "collinear_inputs":              # u_3 = 2 u_1 - u_2
        u[:, 2] = 2 * u[:, 0] - u[:, 1]
    elif name == "zero_input":
        u[:, 1] = 0.0
    elif name == "too_few_rows":                  # few measured outputs: rows < parameters
        keep = np.zeros(n, bool)
        keep[::40] = True
        keep[:8] = True
        keep[170:] = True
        y = np.where(keep, y, np.nan)
    elif name == "input_step_once":               # one step only: lags nearly collinear
        u[:, 2] = np.where(np.arange(n) < 100, 0.0, 1.0)
    return y, u, kw


RANK_CASES = ["constant_input_with_intercept", "constant_input_lags", "collinear_inputs",
              "zero_input", "too_few_rows", "input_step_once"]


@pytest.mark.parametrize("name", RANK_CASES)
def test_full_rank_verdict_agrees_with_solve_wls(name):
    """The batched rank check selects exactly the candidates lstsq's rank check selects."""
    y, u, kw = _rank_deficient_case(name)
    intercept = kw.get("intercept", False)
    w = np.random.default_rng(3).uniform(0.2, 1.0, size=y.size)
    start, stop = 4, 180
    verdicts = []
    for na in (0, 1, 2):
        g = SharedRegression(y, u, na, 4, 0, intercept, w, start, stop)
        nbs = np.array(list(itertools.product(range(0, 5), repeat=3)))
        theta, full_rank = g.fit(nbs)
        for i, nb in enumerate(nbs):
            orders = ArxOrders(na, tuple(nb), 0, intercept)
            if orders.n_params == 0:
                continue
            try:
                m = fit_arx(y, u, orders, w, start=start, stop=stop)
            except RankDeficientError:
                assert not full_rank[i], (na, tuple(nb))
                verdicts.append(False)
                continue
            assert full_rank[i], (na, tuple(nb))
            verdicts.append(True)
            cols = g.columns(tuple(nb))
            np.testing.assert_allclose(theta[i, cols], m.theta, rtol=1e-7, atol=1e-9)
    if name != "input_step_once":
        assert not all(verdicts), "the case must contain rank-deficient candidates"
    assert any(verdicts)


@pytest.mark.parametrize("exhaustive_limit", [4000, 5])     # exhaustive / coordinate search
@pytest.mark.parametrize("name", RANK_CASES)
def test_select_orders_on_rank_deficient_data_matches_the_reference(name, exhaustive_limit):
    """Also: candidates scored in advance by the coordinate search never count as tried or
    rank deficient unless the search asks for them."""
    y, u, kw = _rank_deficient_case(name)
    kw = dict(kw, exhaustive_limit=exhaustive_limit)
    for na_range in NA_RANGES:
        try:
            old = _select_orders_reference(y, u, na_range, (0, 3), **kw)
        except RankDeficientError:
            with pytest.raises(RankDeficientError):
                select_orders(y, u, na_range, (0, 3), **kw)
            continue
        new = select_orders(y, u, na_range, (0, 3), **kw)
        # collinear inputs make distinct candidates the same model (equal scores to rounding):
        # the per-candidate evaluation breaks such ties, so the choice is the same
        assert new.orders == old.orders
        assert new.candidates_rank_deficient == old.candidates_rank_deficient
        assert new.candidates_tried == old.candidates_tried
        assert new.score == pytest.approx(old.score, rel=REL)


def test_theta_of_the_shared_factorisation_is_the_wls_estimate():
    y, u, rng = _random_system(30)
    w = rng.uniform(0.0, 1.0, size=y.size)          # some rows get (almost) no weight
    g = SharedRegression(y, u, 2, 5, 1, True, w, 6, 400)
    nbs = rng.integers(0, 6, size=(40, 3))
    theta, full_rank = g.fit(nbs)
    assert full_rank.all()
    for i, nb in enumerate(nbs):
        m = fit_arx(y, u, ArxOrders(2, tuple(nb), 1, True), w, start=6, stop=400)
        cols = g.columns(tuple(nb))
        np.testing.assert_allclose(theta[i, cols], m.theta, rtol=REL, atol=1e-12)
        others = np.setdiff1d(np.arange(theta.shape[1]), cols)
        assert np.all(theta[i, others] == 0)


def test_solve_wls_and_shared_factorisation_agree_on_rows_short_of_parameters():
    y, u, _ = _random_system(31, n=60)
    y = y.copy()
    y[5:50] = np.nan                                 # 10 rows left for up to 1 + 3 * 4 parameters
    g = SharedRegression(y, u, 1, 4, 0, False, None, 4, 60)
    nbs = np.array(list(itertools.product(range(1, 5), repeat=3)))
    _, full_rank = g.fit(nbs)
    for i, nb in enumerate(nbs):
        orders = ArxOrders(1, tuple(nb))
        phi_rows = g.n_rows
        expect = phi_rows >= orders.n_params
        if expect:
            try:
                fit_arx(y, u, orders, start=4, stop=60)
            except RankDeficientError:
                expect = False
        assert full_rank[i] == expect
    assert full_rank.any() and not full_rank.all()


@pytest.mark.parametrize("na", [1, 2, 3])
def test_pole_check_is_arx_model_is_stable(na):
    rng = np.random.default_rng(na)
    a = rng.uniform(-1.5, 1.5, size=(300, na))
    for i in range(40):        # real poles: positive ones, then of either sign
        a[i] = np.poly(rng.uniform(0.05 if i < 20 else -0.3, 0.99, size=na))[1:]
    for margin, real_positive in [(0.0, False), (0.05, False), (0.0, True), (0.02, True)]:
        got = poles_inside(a, margin, real_positive)
        for i in range(a.shape[0]):
            m = ArxModel(ArxOrders(na, ()), a[i])
            assert got[i] == m.is_stable(margin, real_positive), (a[i], margin, real_positive)
        assert got.any() and not got.all()


@pytest.mark.parametrize("n_cands", [3, 100])       # per-candidate lfilter / vectorised time loop
@pytest.mark.parametrize("na", [0, 1, 2, 3])
@pytest.mark.parametrize("state_updates", [False, True])
def test_batched_simulation_is_arx_model_simulate(na, state_updates, n_cands):
    rng = np.random.default_rng(40 + na)
    n, split, nb_max = 200, 120, 3
    u = rng.normal(size=(n, 2))
    y = np.cumsum(rng.normal(size=n)) * 0.1
    measured = np.zeros(n, bool)
    measured[split + 5::17] = True
    cands = []
    for _ in range(n_cands):
        nb = tuple(int(v) for v in rng.integers(0, nb_max + 1, size=2))
        orders = ArxOrders(na, nb, 0, True)
        a = np.poly(rng.uniform(0.1, 0.9, size=na))[1:] if na else np.zeros(0)
        cands.append(ArxModel(orders, np.concatenate([a, rng.normal(size=sum(nb) + 1)])))
    u_lags = input_lag_matrix(u, nb_max, 0, True, split)
    theta_b = np.zeros((len(cands), u_lags.shape[1]))
    for i, m in enumerate(cands):
        for j, bj in enumerate(m.b):
            theta_b[i, j * nb_max: j * nb_max + bj.size] = bj
        theta_b[i, -1] = m.c
    a = np.array([m.a for m in cands]).reshape(len(cands), na)
    pred = simulate_batch(a, u_lags @ theta_b.T, y[split - na:split],
                          measured[split:] if state_updates else None, y[split:])
    for i, m in enumerate(cands):
        if state_updates:
            ref = m.simulate(u, y, split, measured=measured, y_measured=y)
        else:
            ref = m.simulate(u, y, split)
        np.testing.assert_allclose(pred[:, i], ref[split:], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("r", [0, 1])
@pytest.mark.parametrize("intercept", [False, True])
def test_no_or_one_input(r, intercept):
    """TALC may drop every input (all sensors excluded): an autoregressive / intercept-only search."""
    y, u, _ = _random_system(60, r=1)
    u = u[:, :r]
    for na_range in [(0, 2), (1, 2)]:
        try:
            old = _select_orders_reference(y, u, na_range, (1, 3), intercept=intercept)
        except RankDeficientError:
            with pytest.raises(RankDeficientError):
                select_orders(y, u, na_range, (1, 3), intercept=intercept)
            continue
        new = select_orders(y, u, na_range, (1, 3), intercept=intercept)
        assert new.orders == old.orders and new.candidates_tried == old.candidates_tried
        assert new.score == pytest.approx(old.score, rel=REL)


def test_bad_input_is_named():
    y, u, _ = _random_system(50, n=100)
    with pytest.raises(ValueError, match="weights: shape"):
        select_orders(y, u, (1, 1), (1, 2), weights=np.ones(99))
    u2 = u.copy()
    u2[10, 1] = np.inf
    with pytest.raises(ValueError, match="inputs u"):
        SharedRegression(y, u2, 1, 2, 0, False, None, 2, 60)
    with pytest.raises(ValueError, match="first row"):
        input_lag_matrix(u, 4, 1, False, 2)
    with pytest.raises(ValueError, match="nbs: shape"):
        SharedRegression(y, u, 1, 2, 0, False, None, 2, 60).fit(np.array([1, 2, 1]))
    assert math.isfinite(select_orders(y, u, (1, 1), (1, 2)).score)


@pytest.mark.parametrize("padded", [False, True])
def test_small_solver_rank_and_solution_are_lstsq_s(padded):
    """Condition numbers from 1 to singular, around lstsq's tolerance eps * max(rows, p) too
    (decided there by the SVD fallback), with and without padding columns."""
    from talc_model.arx.batch import _solve_small
    rng = np.random.default_rng(70)
    k, p, n_rows = 30, 8, 500
    limit = 1.0 / (np.finfo(float).eps * n_rows)
    conds = [1.0, 1e3, 1e6, 1e9, limit / 30, limit * 30, 1e20, np.inf]
    mats, sizes = [], []
    for c in conds * 3:
        q_u, _ = np.linalg.qr(rng.normal(size=(k, p)))
        q_v, _ = np.linalg.qr(rng.normal(size=(p, p)))
        s = np.geomspace(1.0, 1.0 / c if np.isfinite(c) else 1e-300, p)
        if not np.isfinite(c):
            s[-1] = 0.0
        mats.append(5.0 * (q_u * s) @ q_v.T)
        sizes.append(p)
    b = rng.normal(size=k)
    sub = np.array(mats)
    p_each = None
    if padded:                       # drop trailing columns of some and pad them as fit() does
        sizes = [int(rng.integers(3, p + 1)) for _ in mats]
        p_each = np.array(sizes)
        pad = np.arange(p)[None, :] >= p_each[:, None]
        sub = np.where(pad[:, None, :], 0.0, sub)
        sub = np.concatenate([sub, pad[:, :, None] * np.eye(p)[None]], axis=1)
    rhs = np.concatenate([b, np.zeros(p)]) if padded else b
    theta, full = _solve_small(sub, rhs, n_rows, p_each)
    for i, (a, pi) in enumerate(zip(mats, sizes)):
        a = a[:, :pi]
        ref, _, rank, sv = np.linalg.lstsq(a, b, rcond=np.finfo(float).eps * max(n_rows, pi))
        assert full[i] == (rank == pi), (i, sv[0] / sv[-1] if sv[-1] else np.inf)
        if sv[-1] > 0 and sv[0] / sv[-1] < 1e7:
            np.testing.assert_allclose(theta[i, :pi], ref, rtol=1e-8, atol=1e-10)
    assert full.any() and not full.all()
