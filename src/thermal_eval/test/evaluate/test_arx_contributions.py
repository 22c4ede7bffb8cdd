"""The ARX model's per-input contributions that evaluate's gain-update rows re-estimate."""
from __future__ import annotations

import numpy as np

from talc_model.arx.model import ArxOrders, fit_arx
from thermal_eval.evaluate.open_loop_models import arx_contributions


def test_arx_contributions_add_up_to_the_simulation():
    rng = np.random.default_rng(3)
    n = 400
    u = np.cumsum(rng.normal(0, 0.1, (n, 2)), axis=0)
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.5 * y[k - 1] - 0.56 * y[k - 2] + 0.2 * u[k, 0] - 0.1 * u[k - 1, 1] + 0.05 + rng.normal(0, 1e-3)
    model = fit_arx(y[:300], u[:300], ArxOrders(2, (1, 2), intercept=True), start=2)
    g = 300
    full = model.simulate(u, y[:g], g)
    base = model.simulate(np.zeros_like(u), y[:g], g)
    x = arx_contributions(model, u, g)
    assert np.allclose(x[:g], 0.0)
    assert np.allclose(base[g:] + x[g:].sum(axis=1), full[g:], atol=1e-9)
