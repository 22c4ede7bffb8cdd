"""The 1-D rod of the TALC thesis, ch. 3: analytic quasi-steady solution and the same rod as
a twin machine (finite volumes), used to check the network integrator against theory.

Dimensionless rod on 0 < x < 1 (u_t = u_xx), u(0, t) = A cos(w t), u(1, t) = 0. The
quasi-steady solution is u = Re{U(x) e^{iwt}} with U(x) = A sinh(B(1-x))/sinh(B),
B = sqrt(i w) (thesis eq. 3.18); the elongation E = alpha * int_0^1 u dx has the transfer
A (cosh B - 1)/(B sinh B). A sensor at x correlates linearly with E where the phase of U(x)
equals the phase of E: x ~ 0.27 for w = 4 pi (thesis §3.2.1).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import brentq


def rod_U(x: np.ndarray | float, omega: float, amplitude: float = 1.0) -> np.ndarray:
    """Complex amplitude U(x) of the quasi-steady temperature."""
    B = np.sqrt(1j * omega)
    return amplitude * np.sinh(B * (1 - np.asarray(x, dtype=float))) / np.sinh(B)


def rod_elongation_transfer(omega: float) -> complex:
    """E / (alpha A) as a complex amplitude: (cosh B - 1) / (B sinh B)."""
    B = np.sqrt(1j * omega)
    return complex((np.cosh(B) - 1) / (B * np.sinh(B)))


def linear_correlation_point(omega: float) -> float:
    """x where the local temperature is in phase with the elongation (no hysteresis loop)."""
    target = np.angle(rod_elongation_transfer(omega))
    return float(brentq(lambda x: np.angle(rod_U(x, omega)) - target, 1e-6, 0.9))


def rod_machine(n: int = 40, alpha: float = 1.0) -> dict:
    """The rod as a twin machine description: ``n`` finite volumes of width h = 1/n at
    x_i = (i + 1/2) h, capacity h, conductance 1/h between neighbours and 2/h to the end
    boundaries; the boundary at x = 0 follows the input ``drive`` and the one at x = 1 is 0.
    The error ``elongation_um`` = alpha * sum_i h u_i (thesis eq. 3.29)."""
    h = 1.0 / n
    nodes = {f"u{i}": {"capacity": h} for i in range(n)}
    links = {f"k{i}": {"between": [f"u{i}", f"u{i + 1}"], "conductance": 1.0 / h} for i in range(n - 1)}
    links["hot_end"] = {"between": ["u0", "hot"], "conductance": 2.0 / h}
    links["cold_end"] = {"between": [f"u{n - 1}", "cold"], "conductance": 2.0 / h}
    return {
        "schema_version": 1, "name": "rod", "description": "1-D rod of thesis ch. 3, dimensionless",
        "inputs": {"drive": {"kind": "environment", "unit": "1", "default": 0.0}},
        "boundaries": {"hot": {"temperature": "drive"}, "cold": {"temperature": 0.0}},
        "initial_state": {"boundary": "cold"},
        "nodes": nodes, "links": links,
        "sensors": {f"x{i}": {"of": f"u{i}"} for i in range(n)},
        "errors": {"elongation_um": {"unit": "um", "terms": {f"u{i}": alpha * h for i in range(n)}}},
    }


def rod_positions(n: int) -> np.ndarray:
    return (np.arange(n) + 0.5) / n
