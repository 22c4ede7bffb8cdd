"""Our least-squares ARX against an independent implementation (sysidentpy's FROLS keeping
every regressor): the same model structure must give the same one-step predictions."""
import numpy as np

from talc_model.arx.model import ArxOrders, fit_arx, regression_matrix


def test_ols_arx_matches_sysidentpy():
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares
    rng = np.random.default_rng(3)
    n = 600
    u = np.cumsum(rng.normal(0, 0.1, (n, 2)), axis=0)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.9 * y[k - 1] + 0.5 * u[k - 1, 0] - 0.2 * u[k - 2, 1] + 0.1 + rng.normal(0, 0.05)
    orders = ArxOrders(1, (3, 3), nk=1, intercept=True)
    ours = fit_arx(y, u, orders)
    peer = FROLS(order_selection=False, n_terms=orders.n_params, ylag=1, xlag=[[1, 2, 3], [1, 2, 3]],
                 estimator=LeastSquares(), basis_function=Polynomial(degree=1))
    with np.errstate(all="ignore"):
        peer.fit(X=u, y=y.reshape(-1, 1))
        pred_peer = np.asarray(peer.predict(X=u, y=y.reshape(-1, 1), steps_ahead=1)).ravel()
    phi, _, rows = regression_matrix(y, u, orders)
    np.testing.assert_allclose(pred_peer[rows], phi @ ours.theta, atol=1e-9)
    assert abs(ours.a[0] + 0.9) < 0.05 and abs(ours.b[0][0] - 0.5) < 0.1
