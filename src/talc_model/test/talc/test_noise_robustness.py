"""Robustness of TALC's identification to probe noise: thermal poles, data per parameter."""
import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders
from talc_model.arx.order_selection import select_orders
from talc_model.talc.model import TalcModel


def test_pole_checks_real_positive_and_time_constant():
    two = ArxOrders(2, (1,))
    real = ArxModel(two, np.array([-(0.9 + 0.5), 0.9 * 0.5, 1.0]))        # poles 0.9, 0.5
    negative = ArxModel(two, np.array([-(0.9 - 0.5), -0.9 * 0.5, 1.0]))   # poles 0.9, -0.5
    complex_ = ArxModel(two, np.array([-1.2, 0.72, 1.0]))                 # 0.6 +- 0.6j
    np.testing.assert_allclose(sorted(real.poles().real), [0.5, 0.9])
    for m in (real, negative, complex_):
        assert m.is_stable()
    assert real.is_stable(real_positive=True)
    assert not negative.is_stable(real_positive=True)
    assert not complex_.is_stable(real_positive=True)
    # a margin bounds the longest time constant: pole 0.9 at 300 s is tau = 47 min
    assert real.is_stable(margin=1 - 0.95) and not real.is_stable(margin=1 - 0.85)


def _thermal_system(seed, n=300, noise=0.05):
    """Two first-order thermal lags (real poles 0.95 and 0.7) driven by step inputs."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, size=(n // 20 + 1, 2)), 20, axis=0)[:n]
    p1, p2 = 0.95, 0.7
    a = np.array([-(p1 + p2), p1 * p2])
    m = ArxModel(ArxOrders(2, (1, 1)), np.r_[a, 1.0, 0.5])
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = m.predict_one(y, u, k)
    return y + rng.normal(0, noise, n), u


def test_order_selection_with_thermal_poles_returns_only_admissible_models():
    for seed in range(4):
        y, u = _thermal_system(seed)
        sel = select_orders(y, u, (1, 4), (1, 3), real_positive_poles=True, max_pole_radius=0.99)
        p = sel.model.poles()
        assert np.all(np.abs(p.imag) <= 1e-6) and np.all(p.real > 0) and np.all(np.abs(p) < 0.99)
        # the admissible model still simulates the validation part well
        assert sel.validation_rms < 0.5 * np.std(y)
    # an impossible bound leaves no candidate
    with pytest.raises(ValueError, match="max_pole_radius"):
        select_orders(y, u, (1, 1), (1, 1), max_pole_radius=1.5)


def test_calibration_needs_enough_measured_samples_per_parameter():
    rng = np.random.default_rng(0)
    n = 120
    u = np.repeat(rng.uniform(-3, 3, size=(n // 4 + 1, 2)), 4, axis=0)[:n]
    true = ArxModel(ArxOrders(1, (2, 2)), np.array([-0.9, 1.0, 0.5, -0.6, 0.8]))
    e = np.zeros(n)
    for k in range(1, n):
        e[k] = true.predict_one(e, u, k)
    ends = {}
    for per_param in (1.0, 5.0):
        m = TalcModel(dict(component_names=["E_X0C"], input_names=["a", "b"], cp_interval_s=205.0,
                           na_max=1, nb_max=2, nb_max_final=2, cp_min_samples_per_parameter=per_param))
        for k in range(n):
            m.update_inputs(k * 300.0, {"a": u[k, 0], "b": u[k, 1]}, {})
            m.predict(k * 300.0)
            if m.probe_due(k * 300.0):
                m.add_measurement(k * 300.0, {"E_X0C": e[k]}, {})
            if m.phase != "calibration":
                ends[per_param] = (m.probing_cycles, m._n_measured())
                break
        else:
            pytest.fail(f"calibration never ended with {per_param} samples per parameter")
    assert ends[1.0][1] >= 5                   # order sum n_a + sum n_b
    assert ends[5.0][1] >= 25                  # 5 x 5 parameters
    assert ends[5.0][0] > ends[1.0][0]
    with pytest.raises(ValueError, match="'cp_min_samples_per_parameter'"):
        TalcModel({"cp_min_samples_per_parameter": 0})
    with pytest.raises(ValueError, match="'max_time_constant_h'"):
        TalcModel({"max_time_constant_h": -1})
