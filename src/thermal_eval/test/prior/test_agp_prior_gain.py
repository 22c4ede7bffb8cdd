"""The AGP prior's gain in the first hours on a lathe unit that is not the nominal type: prior from
the nominal twin on other load programmes and seeds, run on unit #1 (lathe-random-speed, seed 0,
shortened). Figures of the full runs: docs/prior.md, "AGP and characteristic diagrams"."""
import json

import numpy as np
import pytest

from talc_model.agp.model import AdaptiveGaussianProcess
from talc_model.prior.agp import AgpPriorModel, agp_with_prior, build_agp_prior
from thermal_eval.replay.virtual_experiment import run_virtual_experiment
from thermal_twin.machine.instance import machine_instance
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

pytestmark = pytest.mark.slow    # three nominal simulations and a GP fit: minutes on a loaded 2-core VM

CFG = {"components": ["GB_X"], "max_expected_error_um": 40.0}
TRAIN = ["lathe-oil-steps", "lathe-door-openings", "lathe-test-piece"]


def _nominal(scenario, seed, hours):
    return simulate("swiss_lathe", make_timeline("swiss_lathe", scenario, hours=hours, seed=seed), seed=seed).to_recording()


@pytest.fixture(scope="module")
def prior():
    recs = [_nominal(s, 101 + i, 24.0 if s == "lathe-oil-steps" else None) for i, s in enumerate(TRAIN)]
    return build_agp_prior(recs, CFG, machine="swiss_lathe", sources=TRAIN, max_points=200)


@pytest.fixture(scope="module")
def run():
    unit = machine_instance("swiss_lathe", 1)
    return simulate(unit, make_timeline("swiss_lathe", "lathe-random-speed", hours=8.0, seed=0), seed=0).to_recording()


def _replay(rec, model):
    res = run_virtual_experiment(rec, model, probed_components=["GB_X"], probe_noise_um=0.3,
                                 probe_resolution_um=0.1, seed=0)
    r = res.residual["GB_X"]
    return float(np.percentile(np.abs(r), 99)), float(np.sqrt(np.mean(r ** 2))), res.final_status["q_prod_pct"]


def test_prior_beats_the_thesis_start_in_the_first_hours(prior, run):
    p99_no, rms_no, q_no = _replay(run, AdaptiveGaussianProcess(CFG))
    model = agp_with_prior(CFG, prior)
    p99_pr, rms_pr, q_pr = _replay(run, model)
    assert model.phase == "compensation"
    assert p99_pr < 0.6 * p99_no, (p99_pr, p99_no)
    assert q_pr > q_no + 1.0, (q_pr, q_no)


def test_prior_inputs_are_selected_and_validated(prior):
    assert prior["model_kind"] == "agp" and prior["input_names"]
    assert set(prior["sensors"]) <= set(prior["input_names"])
    assert prior["validation_rms"]["GB_X"] < 5.0      # held-out nominal programme, um


def test_state_round_trip_keeps_the_prior(prior, run):
    model = agp_with_prior(CFG, prior)
    _replay(run, model)
    back = AgpPriorModel.from_state(json.loads(json.dumps(model.to_state())))
    assert back.x0 is not None and np.allclose(back.x0, model.x0)
    assert back.predict(0.0)[0]["GB_X"] == pytest.approx(model.predict(0.0)[0]["GB_X"])
