"""MISO ARX: exact recovery, WLS weights, full-rank check, simulation mode."""
import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders, RankDeficientError, fit_arx, regression_matrix, solve_wls


def _simulate_true(theta, orders, u, noise=None):
    m = ArxModel(orders, np.asarray(theta, float))
    y = np.zeros(u.shape[0])
    for k in range(orders.max_lag, u.shape[0]):
        y[k] = m.predict_one(y, u, k) + (0.0 if noise is None else noise[k])
    return y


def _steps(rng, n, m, hold=6):
    return np.repeat(rng.uniform(-1, 1, size=(n // hold + 1, m)), hold, axis=0)[:n]


def test_arx_system_recovered_exactly():
    rng = np.random.default_rng(0)
    orders = ArxOrders(2, (2, 3))
    theta = [-1.2, 0.35, 0.5, -0.3, 0.2, 0.1, -0.25]
    u = _steps(rng, 300, 2)
    y = _simulate_true(theta, orders, u)
    fit = fit_arx(y, u, orders)
    np.testing.assert_allclose(fit.theta, theta, atol=1e-10)
    assert fit.is_stable()


def test_b0_and_delay_convention():
    rng = np.random.default_rng(1)
    u = _steps(rng, 200, 1, hold=3)
    with_b0 = ArxOrders(1, (2,), nk=0)
    without_b0 = ArxOrders(1, (2,), nk=1)
    phi0, _, rows0 = regression_matrix(np.zeros(200), u, with_b0)
    phi1, _, rows1 = regression_matrix(np.zeros(200), u, without_b0)
    k = 10
    i0 = int(np.flatnonzero(rows0 == k)[0])
    i1 = int(np.flatnonzero(rows1 == k)[0])
    assert phi0[i0, 1:].tolist() == [u[k, 0], u[k - 1, 0]]
    assert phi1[i1, 1:].tolist() == [u[k - 1, 0], u[k - 2, 0]]


def test_intercept_estimated():
    rng = np.random.default_rng(2)
    orders = ArxOrders(1, (1,), intercept=True)
    theta = [-0.7, 2.0, 0.4]
    u = _steps(rng, 200, 1)
    y = _simulate_true(theta, orders, u)
    np.testing.assert_allclose(fit_arx(y, u, orders).theta, theta, atol=1e-10)


def test_wls_weights_match_normal_equations_and_select_data():
    rng = np.random.default_rng(3)
    phi = rng.normal(size=(50, 3))
    target = phi @ [1.0, -2.0, 0.5] + rng.normal(scale=0.3, size=50)
    w = rng.uniform(0.01, 1.0, 50)
    theta = solve_wls(phi, target, w)
    expected = np.linalg.solve(phi.T @ (w[:, None] * phi), phi.T @ (w * target))
    np.testing.assert_allclose(theta, expected, rtol=1e-10)
    # two regimes: zero weight on the first one recovers the second exactly
    orders = ArxOrders(1, (2,))
    u = _steps(rng, 400, 1)
    y_a = _simulate_true([-0.5, 1.0, 0.5], orders, u)
    y_b = _simulate_true([-0.8, -1.0, 2.0], orders, u)
    y = np.concatenate([y_a[:200], y_b[200:]])
    weights = np.r_[np.zeros(210), np.ones(190)]
    fit = fit_arx(y, u, orders, weights)
    np.testing.assert_allclose(fit.theta, [-0.8, -1.0, 2.0], atol=1e-9)
    # a small weight on the first regime pulls the estimate only a little
    fit_small = fit_arx(y, u, orders, np.r_[np.full(210, 0.01), np.ones(190)])
    fit_equal = fit_arx(y, u, orders)
    err_small = np.abs(fit_small.theta - [-0.8, -1.0, 2.0]).max()
    err_equal = np.abs(fit_equal.theta - [-0.8, -1.0, 2.0]).max()
    assert err_small < err_equal / 5


def test_rank_deficient_regression_is_reported():
    u = np.ones((100, 2))             # two identical constant inputs: not identifiable
    y = np.linspace(0, 1, 100)
    with pytest.raises(RankDeficientError) as exc:
        fit_arx(y, u, ArxOrders(1, (1, 1)))
    assert exc.value.rank < exc.value.n_params == 3
    with pytest.raises(RankDeficientError):
        fit_arx(y[:3], u[:3], ArxOrders(1, (3, 3)))


def test_bad_weights_rejected():
    with pytest.raises(ValueError, match="weights"):
        solve_wls(np.eye(3), np.ones(3), np.array([1.0, -1.0, 1.0]))


def test_simulation_mode_feeds_back_predictions_and_state_updates():
    rng = np.random.default_rng(4)
    orders = ArxOrders(1, (2, 1))
    theta = np.array([-0.9, 0.5, -0.2, 0.3])
    u = _steps(rng, 120, 2)
    y_true = _simulate_true(theta, orders, u, noise=rng.normal(scale=0.05, size=120))
    m = ArxModel(orders, theta)
    pure = m.simulate(u, y_true, 10)
    # pure simulation = the noise-free recursion from the same initial state
    loop = y_true.copy()
    for k in range(10, 120):
        loop[k] = m.predict_one(loop, u, k)
    np.testing.assert_allclose(pure[10:], loop[10:], atol=1e-10)
    # measuring every sample turns simulation into one-step-ahead prediction
    all_measured = m.simulate(u, y_true, 10, measured=np.ones(120, bool), y_measured=y_true)
    one_step = np.array([m.predict_one(y_true, u, k) for k in range(10, 120)])
    np.testing.assert_allclose(all_measured[10:], one_step, atol=1e-10)
    # a measurement in the middle resets the drift of the recursion
    meas = np.zeros(120, bool)
    meas[60] = True
    mid = m.simulate(u, y_true, 10, measured=meas, y_measured=y_true)
    assert abs(mid[61] - m.predict_one(y_true, u, 61)) < 1e-12


def test_unstable_model_detected_and_state_round_trip():
    m = ArxModel(ArxOrders(1, (1,)), np.array([-1.05, 1.0]))
    assert not m.is_stable()
    d = m.to_state()
    m2 = ArxModel.from_state(d)
    np.testing.assert_array_equal(m2.theta, m.theta)
    d["theta"] = [1.0]
    with pytest.raises(ValueError, match="theta"):
        ArxModel.from_state(d)
