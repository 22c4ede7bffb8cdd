"""Order selection: the criteria's formulas and the true orders found on a known system."""
import math

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders, RankDeficientError
from talc_model.arx.order_selection import criterion_value, select_orders


def _known_system(seed, n=400, noise=0.01):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, size=(n // 8 + 1, 2)), 8, axis=0)[:n]
    orders = ArxOrders(1, (2, 3))
    m = ArxModel(orders, np.array([-0.8, 0.5, -0.3, 0.2, 0.1, -0.25]))
    y = np.zeros(n)
    for k in range(orders.max_lag, n):
        y[k] = m.predict_one(y, u, k) + rng.normal(scale=noise)
    return y, u


@pytest.mark.parametrize("criterion", ["mdl", "bic"])   # the consistent criteria; AIC may overfit
def test_criterion_picks_the_true_orders(criterion):
    """Order selection is statistical: over 10 noise realisations the true orders must win
    at least 8 times (a wrong pick is always a neighbouring, over-fitted order)."""
    hits = 0
    for seed in range(10):
        y, u = _known_system(seed)
        sel = select_orders(y, u, (1, 3), (1, 5), criterion=criterion)
        assert sel.candidates_tried == 3 * 25
        assert sel.validation_rms < 0.05
        hits += (sel.orders.na, sel.orders.nb) == (1, (2, 3))
    assert hits >= 8


def test_coordinate_search_finds_the_true_orders_too():
    y, u = _known_system(1)
    sel = select_orders(y, u, (1, 3), (1, 5), criterion="mdl", exhaustive_limit=10)
    assert (sel.orders.na, sel.orders.nb) == (1, (2, 3))
    assert sel.candidates_tried < 3 * 25


def test_criterion_formulas_by_hand():
    res = np.array([1.0, -1.0, 2.0, -2.0])           # V = 2.5, N = 4
    o = ArxOrders(1, (2, 3))                           # d = 6, N_ord = 6
    assert criterion_value("mdl", res, o) == pytest.approx(2.5 * (1 + 6 * math.log(4) / 4))
    assert criterion_value("mdl_as_printed", res, o) == pytest.approx(math.sqrt(2.5) * (1 + math.log(6) / 6))
    assert criterion_value("aic", res, o) == pytest.approx(4 * math.log(2.5) + 12)
    assert criterion_value("bic", res, o) == pytest.approx(4 * math.log(2.5) + 6 * math.log(4))
    with pytest.raises(ValueError, match="criterion"):
        criterion_value("cp", res, o)


def test_as_printed_penalty_prefers_larger_orders_for_equal_fit():
    """Eq. 4.23's factor 1 + ln(N)/N falls for N >= 3: documented reason for the default."""
    res = np.ones(10)
    small = criterion_value("mdl_as_printed", res, ArxOrders(1, (1, 1)))
    large = criterion_value("mdl_as_printed", res, ArxOrders(1, (5, 5)))
    assert large < small
    assert criterion_value("mdl", res, ArxOrders(1, (5, 5))) > criterion_value("mdl", res, ArxOrders(1, (1, 1)))


def test_too_little_data_raises_rank_error_and_bad_ranges_raise():
    y, u = _known_system(2, n=12)
    with pytest.raises(RankDeficientError):
        select_orders(y, u, (1, 1), (5, 5))
    with pytest.raises(ValueError, match="order ranges"):
        select_orders(y, u, (2, 1), (1, 2))
    with pytest.raises(ValueError, match="inputs u"):
        u2 = u.copy()
        u2[3, 0] = np.nan
        select_orders(y, u2, (1, 1), (1, 2))
