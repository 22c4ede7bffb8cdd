"""Quality indicators against hand-computed values."""
import math

import numpy as np
import pytest

from thermal_comp_common import metrics

E = np.array([2.0, -4.0, 6.0, 8.0])
EH = np.array([1.0, -5.0, 6.0, 10.0])      # residuals 1, 1, 0, -2


def test_rms():
    assert metrics.e_rms(E, EH) == pytest.approx(math.sqrt((1 + 1 + 0 + 4) / 4))


def test_smap_with_and_without_the_underestimation_conversion():
    # without conversion: |r| / (|E| + |Ê|), all samples non-zero
    raw = (1 / 3 + 1 / 9 + 0 / 12 + 2 / 18) / 4 * 100
    assert metrics.e_smap(E, EH, convert_underestimation=False) == pytest.approx(raw)
    conv = (1 / 5 + 1 / 9 + 0 / 12 + 2 / 18) / 4 * 100
    assert metrics.e_smap(E, EH) == pytest.approx(conv)
    # samples with E == 0 or Ê == 0 are left out
    assert metrics.e_smap([0.0, 2.0], [1.0, 1.0], convert_underestimation=False) == pytest.approx(100 / 3)


def test_pv_as_printed():
    assert metrics.e_pv(E, EH) == pytest.approx((1 + 2) / (8 + 4) * 100)


def test_p99_is_hazen():
    r = np.arange(1.0, 11.0)       # |residuals| 1..10, N = 10
    # hazen: k = N*X + 1/2 = 10.4 > N -> clamps to the largest value
    assert metrics.p99(r, np.zeros(10)) == pytest.approx(10.0)
    # P50 of 1..10: k = 5.5 -> R_5 + 0.5 (R_6 - R_5) = 5.5
    assert metrics.px(r, np.zeros(10), 50) == pytest.approx(5.5)
    # P90: k = 9.5 -> 9.5
    assert metrics.px(r, np.zeros(10), 90) == pytest.approx(9.5)
    # p1 = 0.05 -> below the first plotting position gives the smallest value
    assert metrics.px(r, np.zeros(10), 2) == pytest.approx(1.0)


def test_q_prod_and_reductions():
    assert metrics.q_prod(10, 10 * 3600.0) == pytest.approx(100 * (1 - 950 / 36000))
    e = np.array([0.0, 10.0, -10.0, 20.0])
    eh = np.array([0.0, 8.0, -9.0, 17.0])      # residual 0, 2, -1, 3
    u = math.sqrt((100 + 100 + 400) / 4)
    c = math.sqrt((4 + 1 + 9) / 4)
    assert metrics.rms_reduction(e, eh) == pytest.approx(100 * (u - c) / u)
    assert metrics.p2p_reduction(e, eh) == pytest.approx(100 * (30 - 4) / 30)


def test_p99_group_and_bad_input():
    assert metrics.p99_group({"a": 2.0, "b": 4.0, "c": 9.0}, ["a", "b"]) == 3.0
    with pytest.raises(ValueError, match="samples"):
        metrics.e_rms([1, 2], [1, 2, 3])
    with pytest.raises(ValueError, match="finite"):
        metrics.e_rms([np.nan], [1.0])
