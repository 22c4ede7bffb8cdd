"""Re-choosing twin init's structure on the next day's probes: a twin's open loop driven by a
recording reproduces the simulator's errors, the candidate closest to the probes ranks first by
the noise-normalised SSE, and bad probe rows are refused naming the field."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from thermal_twin.identify import open_loop, probe_cost, rank_on_probes
from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.sim.simulate import simulate

TWIN = {
    "schema_version": 1, "name": "rig", "initial_state": "steady",
    "inputs": {"speed": {"kind": "machine", "default": 0, "min": 0, "max": 6000},
               "ambient_degc": {"kind": "environment", "default": 20.0, "from_sensor": "hall"}},
    "boundaries": {"ambient": {"temperature": "ambient_degc"}},
    "nodes": {"motor": {"capacity": 4.0e4}, "frame": {"capacity": 2.0e6}},
    "links": {"m_a": {"between": ["motor", "ambient"], "conductance": 4.0},
              "m_f": {"between": ["motor", "frame"], "conductance": 10.0},
              "f_a": {"between": ["frame", "ambient"], "conductance": 25.0}},
    "sources": {"losses": {"node": "motor", "input": "speed", "coefficient": 0.05, "exponent": 1.0}},
    "sensors": {"hall": {"of": "ambient"}, "s_motor": {"of": "motor"}},
    "errors": {"z_um": {"unit": "um", "terms": {"motor": 1.0, "frame": 6.0}}},
}


@pytest.fixture(scope="module")
def run():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 48 * 3600.0 + 1, 300.0)
    speed = rng.uniform(0, 6000, 49)[(t // 3600).astype(int)]
    hall = 20.0 + 2.0 * np.sin(2 * np.pi * t / 86400.0)
    return simulate(TWIN, InputsTimeline(t, {"speed": speed, "ambient_degc": hall}), seed=3).to_recording()


def _without_frame_gain():
    spec = copy.deepcopy(TWIN)
    spec["errors"]["z_um"]["terms"]["frame"] = 0.0
    return spec


def test_the_open_loop_reproduces_the_simulated_errors(run):
    z = open_loop(TWIN, run)["z_um"]
    assert z.shape == (len(run),) and np.allclose(z, run.columns["z_um"], atol=1e-6 + 1e-6 * np.ptp(z))


def test_the_candidate_closest_to_the_next_days_probes_ranks_first(run):
    rows = np.arange(len(run) // 2, len(run), 6)              # day 2, one probe every 30 min
    rng = np.random.default_rng(0)
    values = {"z_um": np.asarray(run.columns["z_um"], float)[rows] + rng.normal(0.0, 0.25, rows.size)}
    ranked = rank_on_probes({0: _without_frame_gain(), 1: TWIN}, run, rows, values, {"z_um": 0.25})
    assert [r.hidden for r in ranked] == [1, 0]
    # the true twin's cost is about one probe noise per channel; the wrong one's many
    assert 0.5 < ranked[0].cost < 2.0 < 10.0 < ranked[1].cost
    assert ranked[0].predicted["z_um"].shape == rows.shape


def test_the_cost_is_the_noise_normalised_sse_over_channels_with_probes():
    v = {"a": np.array([1.0, np.nan, 3.0]), "b": np.array([np.nan, np.nan, np.nan])}
    p = {"a": np.array([0.0, 5.0, 3.0]), "b": np.array([1.0, 1.0, 1.0])}
    assert probe_cost(v, {"a": 0.5, "b": 1.0}, p) == pytest.approx((math.sqrt(0.5) / 0.5) ** 2)
    assert probe_cost({"b": v["b"]}, {"b": 1.0}, p) == math.inf


def test_probe_rows_outside_the_recording_are_refused(run):
    with pytest.raises(ValueError, match="probe_rows"):
        rank_on_probes({1: TWIN}, run, np.array([0, len(run)]), {"z_um": np.zeros(2)}, {"z_um": 0.25})
