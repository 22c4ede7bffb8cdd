"""Per-component probe noise in the virtual experiment (linear um, angular um/m)."""
import math

import numpy as np
import pytest

from talc_model.adaptive_model import ModelStatusData
from thermal_twin.sim.synthetic_plant import make_plant
from thermal_eval.replay.virtual_experiment import (VirtualExperimentError, probe_noise_by_component,
                                           run_virtual_experiment)

COMPONENTS = ["E_X0C", "E_A0C"]


class ProbeEveryStep:
    """Never compensates, probes at every step and keeps what the probe saw."""

    kind = "probe_log"
    component_names = COMPONENTS

    def __init__(self):
        self.seen = {c: [] for c in COMPONENTS}

    def update_inputs(self, t_s, temperatures, machine_state):
        pass

    def predict(self, t_s):
        return {c: 0.0 for c in COMPONENTS}, {c: math.nan for c in COMPONENTS}

    def probe_due(self, t_s):
        return True

    def add_measurement(self, t_s, measured, applied_compensation):
        for c in COMPONENTS:
            self.seen[c].append(measured[c])

    def add_failed_measurement(self, t_s, reason):
        raise AssertionError(reason)

    def status(self, t_s):
        return ModelStatusData(phase="compensation")


def _noise_seen(noise, seed=3):
    rec = make_plant(hours=40.0, step_s=300.0, seed=2).as_recording()
    model = ProbeEveryStep()
    res = run_virtual_experiment(rec, model, probe_noise_um=noise, seed=seed, compute_metrics=False)
    return {c: np.asarray(model.seen[c]) - res.true[c] for c in COMPONENTS}


def test_linear_and_angular_components_get_their_own_noise():
    noise = probe_noise_by_component(COMPONENTS, 0.25, 1.2, ["E_A0C"])
    assert noise == {"E_X0C": 0.25, "E_A0C": 1.2}
    d = _noise_seen(noise)
    # 481 samples: the sample std is within ~10 % of the true one
    assert np.std(d["E_X0C"]) == pytest.approx(0.25, rel=0.15)
    assert np.std(d["E_A0C"]) == pytest.approx(1.2, rel=0.15)
    # a single value still applies to every component, and the seed fixes the draw
    same = _noise_seen(0.5)
    assert np.std(same["E_X0C"]) == pytest.approx(0.5, rel=0.15)
    assert np.std(same["E_A0C"]) == pytest.approx(0.5, rel=0.15)
    np.testing.assert_array_equal(_noise_seen(noise)["E_A0C"], d["E_A0C"])


def test_bad_noise_mapping_names_the_component():
    rec = make_plant(hours=2.0, step_s=300.0, seed=2).as_recording()
    with pytest.raises(VirtualExperimentError, match=r"no value for probed component\(s\) \['E_A0C'\]"):
        run_virtual_experiment(rec, ProbeEveryStep(), probe_noise_um={"E_X0C": 0.25})
    with pytest.raises(VirtualExperimentError, match=r"probe_noise_um\['E_A0C'\]: -1"):
        run_virtual_experiment(rec, ProbeEveryStep(), probe_noise_um={"E_X0C": 0.25, "E_A0C": -1})
