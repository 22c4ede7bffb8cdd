"""The probe-and-hold baseline: its interval from Q_prod, what it holds, its P99."""
import math

import numpy as np
import pytest

from thermal_comp_common.metrics import q_prod
from thermal_comp_common.probe_and_hold import hold_compensation, probe_and_hold, probe_interval_s


def test_interval_gives_the_same_q_prod():
    dt = probe_interval_s(97.0, 95.0)
    n = 1000
    assert q_prod(n, n * dt, 95.0) == pytest.approx(97.0)


def test_holds_the_last_probe_strictly_before_each_instant():
    t = np.arange(0.0, 10.0)
    e = t * 2.0
    comp = hold_compensation(t, e, 4.0, 0.0, 0.0, np.random.default_rng(0))
    # probes at rows 0, 4, 8; held from the next instant on
    assert comp.tolist() == [0, 0, 0, 0, 0, 8, 8, 8, 8, 16]


def test_p99_of_a_ramp_is_the_drift_over_one_interval():
    t = np.arange(0.0, 100 * 3600.0, 60.0)
    e = t / 3600.0                       # 1 um per hour
    out = probe_and_hold(t, {"E_X0C": e}, 95.0, {"E_X0C": 0.0}, window=t > 3600.0)
    interval_h = 95.0 / 0.05 / 3600.0
    assert out["interval_h"] == pytest.approx(interval_h)
    assert out["components"]["E_X0C"]["p99"] == pytest.approx(interval_h, rel=0.05)
    assert out["p99_lin_um"] == out["components"]["E_X0C"]["p99"]
    assert math.isnan(out["p99_ang_um_per_m"])


def test_noise_and_resolution_are_applied_with_the_seed():
    t = np.arange(0.0, 48 * 3600.0, 300.0)
    e = np.zeros_like(t)
    a = probe_and_hold(t, {"E_A0C": e}, 97.0, {"E_A0C": 1.2}, 0.25, seed=1)
    b = probe_and_hold(t, {"E_A0C": e}, 97.0, {"E_A0C": 1.2}, 0.25, seed=1)
    assert a["components"] == b["components"]
    assert 1.5 < a["components"]["E_A0C"]["p99"] < 5.0
    assert a["components"]["E_A0C"]["unit"] == "um/m"


@pytest.mark.parametrize("q", [100.0, -1.0, math.nan])
def test_bad_q_prod_is_refused(q):
    with pytest.raises(ValueError, match="q_prod_pct"):
        probe_interval_s(q, 95.0)
