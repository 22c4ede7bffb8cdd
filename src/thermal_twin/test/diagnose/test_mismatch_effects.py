"""The effect library edits a valid twin, the fast evaluation equals the twin's simulate,
and implausible fits are recognised as such."""
from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest

from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.machine.schema import load_machine
from thermal_eval.diagnose.concealed import operating_programme
from thermal_twin.diagnose.effects import (EFFECTS, candidates, classify_driver, heat_source,
                                           periodic_amplitude_phase, time_lag_sensor)
from thermal_twin.diagnose.fit import noise_free
from thermal_twin.diagnose.twin_eval import expected_outputs
from thermal_twin.sim.simulate import simulate

HERE = pathlib.Path(__file__).parent
SPEC = load_machine(HERE / "mini_mill.yaml").to_dict()


def _drivers(tl):
    return {k: classify_driver(k, v) for k, v in tl.values.items()}


def test_every_effect_of_the_vocabulary_has_candidates_that_load():
    tl = operating_programme(SPEC, 24.0, 300.0, seed=0)
    chans = [f"{s}_c" for s in SPEC["sensors"]] + list(SPEC["errors"])
    cands = candidates(SPEC, _drivers(tl), chans)
    assert {c.effect for c in cands} == set(EFFECTS) - {"none"}
    for c in cands:
        m = load_machine(c.apply(SPEC, [p.x0 for p in c.params]))   # raises on an invalid edit
        assert m.name == SPEC["name"]
    assert SPEC == load_machine(HERE / "mini_mill.yaml").to_dict(), "apply must not alter its input"


def test_fast_evaluation_equals_twin_simulate():
    """Noise-free twin with every kind of edit at once, uneven time steps."""
    tl0 = operating_programme(SPEC, 30.0, 240.0, seed=7)
    t = tl0.time_s.copy()
    t[1::3] += 37.0                          # uneven steps
    tl = InputsTimeline(t, tl0.values)
    spec = noise_free(SPEC)
    chans = [f"{s}_c" for s in spec["sensors"]] + list(spec["errors"])
    cands = {c.key: c for c in candidates(spec, _drivers(tl), chans)}
    for key, v in [("time_lag:head:-", [900.0]), ("time_lag:E_Z0T:-", [1800.0]),
                   ("speed_dependent_convection:spindle:spindle_rpm", [5.0]),
                   ("door_event:table:door_open", [20.0]), ("coolant:column:coolant_on", [6.0, 17.0]),
                   ("periodic_load:head:-", [20.0, -10.0]), ("sensor_bias:table:-", [0.4]),
                   ("heat_source:head:spindle_rpm", [30.0, 1.4])]:
        spec = cands[key].apply(spec, v)
    m = load_machine(spec)
    ref = simulate(m, tl).columns()
    fast = expected_outputs(m, tl.time_s, tl.resolved(m))
    for k, v in fast.items():
        assert np.max(np.abs(v - ref[k])) < 1e-8 * max(1.0, np.ptp(ref[k])), k


def test_implausible_fits_are_named():
    d = classify_driver("spindle_rpm", np.array([0.0, 12000.0]))
    hs = heat_source(SPEC, "table", d)
    assert "wrong sign" in hs.implausible([-30.0, 1.0])
    assert "exponent" in hs.implausible([30.0, 2.9])
    assert "cannot be" not in (hs.implausible([30.0, 1.0]) or "") and hs.implausible([30.0, 1.0]) is None
    assert "outside the physical range" in hs.implausible([9000.0, 1.0])
    lag = time_lag_sensor(SPEC, "head")
    assert lag.implausible([600.0]) is None
    assert "tau" in lag.implausible([20 * 3600.0])


@pytest.mark.parametrize("a,b", [(30.0, 20.0), (-15.0, 25.0), (0.0, -5.0)])
def test_periodic_amplitude_phase_is_the_same_sinusoid(a, b):
    amp, phase = periodic_amplitude_phase([a, b])
    t = np.linspace(0, 86400, 97)
    w = 2 * math.pi / 86400.0
    assert np.allclose(a * np.sin(w * t) + b * np.cos(w * t), amp * np.sin(w * (t - phase)), atol=1e-9)
