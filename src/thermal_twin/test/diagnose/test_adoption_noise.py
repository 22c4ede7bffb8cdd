"""A recorder that quantises more coarsely than the twin's sensors: the readings' own lattice
step sets the channel's noise floor."""
from __future__ import annotations

import math

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_twin.diagnose.fit import FitProblem, quantisation_step


def _slow_signal(n: int = 600, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 20.0 + np.cumsum(rng.normal(0.0, 0.004, n))


def test_the_lattice_of_quantised_readings_is_found_and_continuous_readings_have_none():
    x = _slow_signal()
    assert quantisation_step(x) == 0.0
    for q in (0.01, 0.0625, 0.1):
        assert math.isclose(quantisation_step(np.round(x / q) * q), q, rel_tol=1e-6)
    assert math.isclose(quantisation_step(np.round(x / 0.1) * 0.1 + 0.03), 0.1, rel_tol=1e-6)
    assert quantisation_step(np.full(50, 20.0)) == 0.0


def test_a_staircase_reading_is_weighted_by_its_step_not_its_flat_second_differences():
    """Noise far below the step: the second differences are mostly zero, so without the
    step the channel's sigma would be a fraction of what the reading errs by."""
    rng = np.random.default_rng(1)
    x = _slow_signal() + rng.normal(0.0, 0.005, 600)
    q = 0.0625
    stair = np.round(x / q) * q
    t = np.arange(600) * 60.0
    rec = Recording(t, {"a_c": stair})
    blind = FitProblem(rec, ["a_c"], 400).sigma["a_c"]
    told = FitProblem(rec, ["a_c"], 400, resolution={"a_c": quantisation_step(stair)}).sigma["a_c"]
    assert blind < 0.5 * q / math.sqrt(12.0)
    assert told >= q / math.sqrt(12.0)
