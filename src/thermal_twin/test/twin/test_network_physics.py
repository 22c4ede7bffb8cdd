"""The thermal network core against physics: analytic steady state, exactness of the step,
energy balance, and the 1-D rod of the TALC thesis (ch. 3)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.machine.schema import load_machine
from thermal_twin.physics.rod_reference import (linear_correlation_point, rod_elongation_transfer, rod_machine,
                                        rod_positions, rod_U)
from thermal_twin.sim.simulate import simulate
from thermal_twin.physics.thermal_network import ThermalNetwork

# motor (source) -> housing -> ambient, housing -> coolant when on, convection growing with speed
SMALL = {
    "name": "small",
    "inputs": {"rpm": {"default": 0, "min": 0, "max": 5000},
               "cool_on": {"default": 0, "min": 0, "max": 1},
               "amb": {"kind": "environment", "default": 20.0}},
    "boundaries": {"ambient": {"temperature": "amb"}, "coolant": {"temperature": 16.0}},
    "nodes": {"motor": {"capacity": 2.0e4}, "housing": {"capacity": 1.5e5}},
    "links": {"mh": {"between": ["motor", "housing"], "conductance": 10.0},
              "ha": {"between": ["housing", "ambient"], "conductance": 5.0,
                     "varies_with": {"rpm": {"per_unit": 0.01, "exponent": 1.0}}},
              "hc": {"between": ["housing", "coolant"], "conductance": 0.0,
                     "varies_with": {"cool_on": {"per_unit": 20.0}}}},
    "sources": {"loss": {"node": "motor", "input": "rpm", "coefficient": 0.1, "exponent": 1.0, "power": 5.0}},
    "sensors": {"housing": {"of": "housing"}},
    "errors": {"E_Z0T": {"unit": "um", "terms": {"housing": 2.0, "motor": 0.5}}},
}


def test_steady_state_equals_the_hand_solved_network():
    net = ThermalNetwork(load_machine(SMALL))
    rpm, amb = 2000.0, 21.0
    p = 5.0 + 0.1 * rpm                                  # W into the motor
    g_ha = 5.0 + 0.01 * rpm
    # coolant off: series path motor -> housing -> ambient
    x = net.steady_state({"rpm": rpm, "amb": amb, "cool_on": 0})
    housing = amb + p / g_ha
    assert x[1] == pytest.approx(housing, rel=1e-12)
    assert x[0] == pytest.approx(housing + p / 10.0, rel=1e-12)
    # coolant on: the housing node balances to ambient and coolant in parallel
    x = net.steady_state({"rpm": rpm, "amb": amb, "cool_on": 1})
    housing = (p + g_ha * amb + 20.0 * 16.0) / (g_ha + 20.0)
    assert x[1] == pytest.approx(housing, rel=1e-12)
    assert x[0] == pytest.approx(housing + p / 10.0, rel=1e-12)


def test_long_simulation_settles_on_the_analytic_steady_state():
    m = load_machine(SMALL)
    tl = InputsTimeline.constant(200 * 3600.0, 3600.0, rpm=3000.0, amb=22.0)
    r = simulate(m, tl)
    p, g_ha = 5.0 + 300.0, 5.0 + 30.0
    assert r.node_temperatures[-1, 1] == pytest.approx(22.0 + p / g_ha, abs=1e-9)
    assert r.node_temperatures[-1, 0] == pytest.approx(22.0 + p / g_ha + p / 10.0, abs=1e-9)


def test_one_long_step_equals_many_short_steps_and_a_stiff_ode_solver():
    net = ThermalNetwork(load_machine(SMALL))
    u = {"rpm": 4000.0, "amb": 19.0, "cool_on": 1}
    x0 = np.array([35.0, 24.0])
    one = net.step(x0, u, 0.0, 7200.0)
    many = x0.copy()
    for k in range(720):
        many = net.step(many, u, 10.0 * k, 10.0)
    np.testing.assert_allclose(one, many, rtol=0, atol=1e-9)
    K, Kb = net.matrices(u)
    f = Kb @ net.boundary_temperatures(u) + net.source_powers(u, 0.0)
    ode = solve_ivp(lambda t, x: (f - K @ x) / net.capacity, (0, 7200.0), x0, method="Radau",
                    rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(one, ode.y[:, -1], atol=1e-6)


def test_energy_balance_over_switching_regimes():
    """Heat stored = heat from the sources - heat to the boundaries, step by step (exact)."""
    net = ThermalNetwork(load_machine("nmv5000"))
    rng = np.random.default_rng(3)
    x = net.steady_state({"ambient_degc": 20.0})
    stored = sources = to_b = 0.0
    for k in range(300):
        u = {"c_speed_rpm": float(rng.choice([0, 400, 1200])), "coolant_on": float(rng.integers(0, 2)),
             "coolant_temp_degc": float(rng.uniform(18, 28)), "ambient_degc": float(rng.uniform(15, 25))}
        x, e = net.step_energy(x, u, 600.0 * k, 600.0)
        assert e.stored == pytest.approx(e.from_sources - e.to_boundaries, rel=1e-7, abs=1e-3)
        stored += e.stored
        sources += e.from_sources
        to_b += e.to_boundaries
    assert sources > 1e6                      # the run did put heat in
    assert stored == pytest.approx(sources - to_b, rel=1e-7, abs=1e-2)


# ---------------------------------------------------------------------------- the rod
OMEGA = 4 * np.pi
N = 40


@pytest.fixture(scope="module")
def rod_run():
    m = load_machine(rod_machine(N))
    dt = 2 * np.pi / OMEGA / 200
    t = np.arange(0.0, 3.0 + dt / 2, dt)
    # boundary held over each step at its mid-step value (a centred zero-order hold)
    tl = InputsTimeline(t, {"drive": np.cos(OMEGA * (t + dt / 2))})
    r = simulate(m, tl)
    keep = t >= 2.0                            # transients decay like exp(-pi^2 t)
    return t[keep], r.node_temperatures[keep], r.errors["elongation_um"][keep]


def _amp_phase(t, y):
    """Least-squares amplitude and phase of y ~ a cos(w t + phi)."""
    A = np.column_stack([np.cos(OMEGA * t), -np.sin(OMEGA * t), np.ones_like(t)])
    c, s, _ = np.linalg.lstsq(A, y, rcond=None)[0]
    return np.hypot(c, s), np.arctan2(s, c)


def test_rod_phase_lag_grows_along_the_rod_as_the_analytic_solution(rod_run):
    t, X, _ = rod_run
    x = rod_positions(N)
    amp, phase = np.array([_amp_phase(t, X[:, i]) for i in range(N)]).T
    phase = np.unwrap(phase)
    assert np.all(np.diff(phase) < 0), "phase lag must grow monotonically away from the heated end"
    U = rod_U(x, OMEGA)
    np.testing.assert_allclose(phase, np.unwrap(np.angle(U)), atol=0.03)
    np.testing.assert_allclose(amp, np.abs(U), atol=0.01)


def test_rod_elongation_and_linear_correlation_point(rod_run):
    t, X, E = rod_run
    amp, phase = _amp_phase(t, E)
    G = rod_elongation_transfer(OMEGA)
    assert amp == pytest.approx(abs(G), abs=0.005)           # 0.322 (spec §1.2)
    assert phase == pytest.approx(np.angle(G), abs=0.03)     # -0.688 rad
    r = np.array([np.corrcoef(X[:, i], E)[0, 1] for i in range(N)])
    k = int(np.argmax(r))
    # the peak between grid nodes: vertex of the parabola through the three best points
    y0, y1, y2 = r[k - 1], r[k], r[k + 1]
    x_best = rod_positions(N)[k] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) / N
    assert linear_correlation_point(OMEGA) == pytest.approx(0.272, abs=0.002)
    assert x_best == pytest.approx(0.27, abs=0.01)
    assert r.max() > 0.999                                    # a line, no hysteresis loop there
    assert r[-1] < r.max() - 0.05                             # far from the source: a loop
