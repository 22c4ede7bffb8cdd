"""The twin's time constants at rest and the rule that a hidden body may not leave a mode slower
than the data it was fitted on (thermal_twin.identify.modes, identification.identifiable)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from thermal_twin.identify.identification import MODE_LIMIT, Candidate, identifiable
from thermal_twin.identify.modes import slowest_mode_h, time_constants_h


def _spec(c1: float, c2: float, g1: float, g12: float, g2: float) -> dict:
    return {"nodes": {"a": {"capacity": c1}, "b": {"capacity": c2}},
            "links": {"a_hall": {"between": ["a", "ambient"], "conductance": g1},
                      "a_b": {"between": ["a", "b"], "conductance": g12},
                      "b_hall": {"between": ["ambient", "b"], "conductance": g2}}}


def test_time_constants_are_the_eigenvalues_of_the_network_at_rest():
    # uncoupled: each node's own C/G
    tau = time_constants_h(_spec(3.6e5, 7.2e5, 10.0, 0.0, 10.0))
    assert tau == pytest.approx([20.0, 10.0])
    # coupled: the eigenvalues of C^-1 G, computed directly
    c, g1, g12, g2 = np.array([1e5, 4e6]), 5.0, 8.0, 2.0
    g = np.array([[g1 + g12, -g12], [-g12, g2 + g12]])
    ref = sorted(1.0 / np.linalg.eigvals(np.diag(1 / c) @ g).real / 3600.0, reverse=True)
    assert time_constants_h(_spec(*c, g1, g12, g2)) == pytest.approx(ref)


def test_a_body_with_no_path_to_a_boundary_is_an_integrator():
    assert math.isinf(slowest_mode_h(_spec(1e5, 1e5, 0.0, 0.0, 10.0)))


def test_a_structure_with_a_mode_slower_than_its_data_is_not_identifiable():
    def cand(slowest):
        return Candidate(1, {}, None, {}, 0.1, slowest_h=slowest, fitted_h=18.0)
    assert identifiable(cand(0.99 * MODE_LIMIT * 18.0))
    assert not identifiable(cand(1.01 * MODE_LIMIT * 18.0))
    assert not identifiable(cand(math.inf))
