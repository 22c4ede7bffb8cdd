"""The screening's analytic output changes (sensor bias, elastic gain, lag of a sensor
without one) equal the simulated twin's to 1e-9, for every start value of every such
candidate of the mini_mill twin."""
from __future__ import annotations

import pathlib

import numpy as np

from thermal_eval.diagnose.concealed import concealed_recording
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.diagnosis import shared_channels
from thermal_twin.diagnose.effects import EFFECTS, candidates, classify_driver
from thermal_twin.diagnose.fit import FitProblem, _starts, linear_change

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()


def test_analytic_changes_equal_the_simulated_twin():
    rec, _ = concealed_recording(SPEC, (), hours=24.0, step_s=300.0, seed=1)
    m = load_machine(SPEC)
    chans = shared_channels(m, rec)
    nt = 200
    fp = FitProblem(rec, chans, nt)
    y0 = fp.outputs(SPEC, stop=nt)
    drivers = {k: classify_driver(k, v) for k, v in rec.inputs.items()}
    cache: dict = {}
    kinds = set()
    for c in candidates(SPEC, drivers, chans, EFFECTS):
        for v in _starts(c):
            dy = linear_change(fp, SPEC, c, v, y0, cache)
            if dy is None:
                continue
            kinds.add(c.effect)
            ref = fp.outputs(c.apply(SPEC, v), stop=nt) - y0
            assert np.max(np.abs(dy - ref)) <= 1e-9 * max(1.0, float(np.max(np.abs(ref)))), c.key
    assert kinds == {"sensor_bias", "elastic_gain", "time_lag"}
