"""The differentiator bound of order selection (max_input_gain_ratio)."""
import math

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders
from talc_model.arx.order_selection import _select_orders_reference, select_orders
from talc_model.talc.config import TalcConfig


def _plant(seed=0, n=900):
    """Output = slow first-order response to u0 plus a true derivative response to u1."""
    rng = np.random.default_rng(seed)
    u = np.cumsum(rng.normal(0, 0.05, (n, 2)), axis=0)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.9 * y[k - 1] + 0.3 * u[k, 0] + 4.0 * (u[k, 1] - u[k - 1, 1]) + rng.normal(0, 0.02)
    return y, u


def test_gain_ratio_of_a_model():
    m = ArxModel(ArxOrders(1, (3, 1, 0)), np.array([-0.9, -1.0, -5.0, 6.5, 0.5]))
    np.testing.assert_allclose(m.input_gain_ratios(), [25.0, 1.0, 0.0])   # 12.5 / 0.5
    assert math.isinf(ArxModel(ArxOrders(0, (2,)), np.array([1.0, -1.0])).input_gain_ratios()[0])


@pytest.mark.parametrize("batched", [True, False])
def test_bound_rejects_the_differentiator_and_batched_agrees(batched):
    y, u = _plant()
    select = select_orders if batched else _select_orders_reference
    free = select(y, u, (1, 1), (1, 4))
    assert free.model.input_gain_ratios()[1] > 3.0          # the data do contain a derivative
    bounded = select(y, u, (1, 1), (1, 4), max_input_gain_ratio=3.0)
    assert np.all(bounded.model.input_gain_ratios() <= 3.0 + 1e-9)
    assert bounded.orders != free.orders
    other = (_select_orders_reference if batched else select_orders)(y, u, (1, 1), (1, 4),
                                                                      max_input_gain_ratio=3.0)
    assert other.orders == bounded.orders
    np.testing.assert_allclose(other.model.theta, bounded.model.theta, rtol=1e-9, atol=1e-12)


def test_config_rejects_a_ratio_below_one():
    with pytest.raises(ValueError, match="max_input_gain_ratio"):
        TalcConfig(max_input_gain_ratio=0.5)
    with pytest.raises(ValueError, match="max_input_gain_ratio"):
        select_orders(*_plant(n=200), (1, 1), (1, 2), max_input_gain_ratio=0.5)
