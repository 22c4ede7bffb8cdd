"""AGP and CD priors carry their held-out training programme; a prior whose GPs or diagrams err
far beyond that programme's own uncompensated error (tampered, or built wrong) is refused in one
line before a run starts from it, whatever its hash says."""
import copy

import numpy as np
import pytest

from talc_model.prior.agp import build_agp_prior
from talc_model.prior.cd import build_cd_prior
from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.integrity import check_prior
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

AGP_CFG = {"components": ["GB_X"], "max_expected_error_um": 40.0}
CD_CFG = {"components": ["E_X0C", "E_Y0C"]}


def _recs(machine, scenarios, hours):
    return [simulate(machine, make_timeline(machine, s, hours=hours, seed=101 + i), seed=101 + i).to_recording()
            for i, s in enumerate(scenarios)]


@pytest.fixture(scope="module")
def agp_prior():
    return build_agp_prior(_recs("swiss_lathe", ["lathe-oil-steps", "lathe-door-openings"], 3.0), AGP_CFG,
                           max_points=60)


@pytest.fixture(scope="module")
def cd_prior():
    return build_cd_prior(_recs("nmv5000", ["load-case-A", "load-case-B", "load-case-C"], 24.0), CD_CFG,
                          machine="nmv5000")


def test_sound_priors_pass_and_keep_their_held_out_programme(agp_prior, cd_prior):
    for prior, comps in ((agp_prior, AGP_CFG["components"]), (cd_prior, CD_CFG["components"])):
        check = prior["training_check"]
        assert set(check["errors"]) == set(comps) and len(check["u"]) == len(check["errors"][comps[0]]) > 10
        check_prior(prior)
    assert model_from_prior("agp", AGP_CFG, agp_prior).prior["gps"] == agp_prior["gps"]
    assert model_from_prior("cd", CD_CFG, cd_prior).prior["cds"] == cd_prior["cds"]


def test_x1000_gp_targets_are_refused(agp_prior):
    bad = copy.deepcopy(agp_prior)
    gp = bad["gps"]["GB_X"]
    gp["y_train"] = (np.asarray(gp["y_train"]) * 1000.0).tolist()
    with pytest.raises(PriorError, match=r"component 'GB_X' errs P99 .* on its training programme") as e:
        model_from_prior("agp", AGP_CFG, bad)
    assert "\n" not in str(e.value)


def test_x1000_diagram_coefficients_are_refused(cd_prior):
    bad = copy.deepcopy(cd_prior)
    cd = bad["cds"]["E_Y0C"]
    cd["coef"] = (np.asarray(cd["coef"]) * 1000.0).tolist()
    with pytest.raises(PriorError, match=r"component 'E_Y0C' errs P99 .* above the bound"):
        model_from_prior("cd", CD_CFG, bad)


def test_unreadable_models_are_named(cd_prior):
    bad = copy.deepcopy(cd_prior)
    del bad["cds"]["E_X0C"]["coef"]
    with pytest.raises(PriorError, match=r"prior: cd models are not readable"):
        check_prior(bad)
