"""The characteristic-diagram prior: built from nominal runs with the CD model's own inputs,
the model compensates from the first instant with it, adapts by load-case updates, and a saved
state resumes with its prior."""
import json

import numpy as np
import pytest

from talc_model.adaptive_model import PHASE_COMPENSATION, model_from_state
from talc_model.cd_model import CharacteristicDiagramModel
from talc_model.prior import PriorError
from talc_model.prior_agp import model_from_prior
from talc_model.prior_cd import CdPriorModel, build_cd_prior, cd_inputs, change_gain
from talc_model.cd_model import CdConfig
from thermal_twin.scenarios import make_timeline
from thermal_twin.simulate import simulate

COMPONENTS = ["E_X0C", "E_Y0C"]


@pytest.fixture(scope="module")
def prior():
    recs = [simulate("nmv5000", make_timeline("nmv5000", s, hours=24.0, seed=101 + i), seed=101 + i).to_recording()
            for i, s in enumerate(["load-case-A", "load-case-B", "load-case-C"])]
    return build_cd_prior(recs, {"components": COMPONENTS}, machine="nmv5000", sources=["a", "b", "c"])


def test_inputs_are_the_models_with_temperatures_from_the_first_row():
    rec = simulate("nmv5000", make_timeline("nmv5000", "load-case-A", hours=2.0, seed=3), seed=3).to_recording()
    sensors, names, x = cd_inputs(rec, CdConfig())
    assert names == sensors + [f"d{s}/dt" for s in sensors] and x.shape == (len(rec), 2 * len(sensors))
    assert np.allclose(x[0, :len(sensors)], 0.0)
    col = rec.columns[f"{sensors[0]}_c"]
    assert np.allclose(x[:, 0], col - col[0])


def test_prior_structure_and_bad_priors(prior):
    assert prior["model_kind"] == "cd" and set(prior["cds"]) == set(COMPONENTS)
    for c in COMPONENTS:
        assert 1 <= len(prior["inputs"][c]) <= 3
        assert prior["input_names"][c] == [prior["candidate_names"][i] for i in prior["inputs"][c]]
        assert np.isfinite(prior["validation_rms"][c])
    assert len(prior["anchors"]["u"]) == len(prior["anchors"]["y"]["E_X0C"]) <= 1500
    with pytest.raises(PriorError, match="model_kind"):
        CdPriorModel({}, {**prior, "model_kind": "agp"})
    with pytest.raises(PriorError, match="E_Z0T"):
        CdPriorModel({"components": ["E_Z0T"]}, prior)
    with pytest.raises(PriorError, match="held out"):
        build_cd_prior([object()], {})


def _drive(model, rec, until_h):
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    preds = []
    for k, t in enumerate(rec.time_s):
        if t > until_h * 3600.0:
            break
        model.update_inputs(float(t), {s: float(v[k]) for s, v in sensors.items()}, {})
        if model.probe_due(float(t)):
            model.add_measurement(float(t), {c: float(rec.columns[c][k] - rec.columns[c][0]) for c in COMPONENTS}, {})
        preds.append(model.predict(float(t))[0]["E_Y0C"])
    return preds


def test_compensates_from_the_first_instant_adapts_and_resumes(prior):
    rec = simulate("nmv5000", make_timeline("nmv5000", "talc-178h-dry", hours=12.0, seed=0), seed=0).to_recording()
    with_updates = {**prior, "adaptation": {**prior["adaptation"], "load_case_updates": True, "check_s": 4 * 3600.0}}
    model = model_from_prior("cd", {"components": COMPONENTS, "update_batch": 2}, with_updates)
    assert isinstance(model, CdPriorModel) and model.phase == PHASE_COMPENSATION
    preds = _drive(model, rec, 3.0)
    assert np.any(np.abs(preds[1:]) > 0)                      # the prior's diagrams, before any update
    # the first check_s (4 h) is probed at the calibration interval (30 min), updates every 2 probes
    assert model.probing_cycles == 7 and model.parameter_updates == 3 and set(model.update) == set(COMPONENTS)
    state = json.loads(json.dumps(model.to_state()))
    back = model_from_state(state)
    assert isinstance(back, CdPriorModel) and isinstance(CharacteristicDiagramModel.from_state(state), CdPriorModel)
    t = float(rec.time_s[180])
    assert back.predict(t) == model.predict(t) and np.allclose(back.x0, model.x0)
    _drive(model, rec, 12.0)
    assert model.config.update_probe_interval_s == 4 * 3600.0
    assert model.probing_cycles == 7 + 4                      # 3.5 and 4 h, then every 4 h: 8 and 12 h
    assert back.anchor == state["anchor"] and all([list(x) for x in back.pairs[c]] == state["pairs"][c] for c in COMPONENTS)


def test_change_gain_is_the_measured_least_squares_gain():
    assert change_gain([1.0, 2.0], [1.0, 2.0]) == pytest.approx(1.0)
    assert change_gain([1.0, 2.0], [2.0, 4.0]) == pytest.approx(0.5)
    assert change_gain([1.0, -2.0], [-1.0, 2.0]) == 0.0         # opposite prediction: hold
    assert change_gain([1.0, 2.0], [0.0, 0.0]) == 0.0            # no predicted change: hold
    assert change_gain([3.0], [1.0]) == 1.0                      # at most the diagrams' change


def test_prediction_is_the_last_probe_plus_the_weighted_change(prior):
    rec = simulate("nmv5000", make_timeline("nmv5000", "talc-178h-dry", hours=3.0, seed=0), seed=0).to_recording()
    model = model_from_prior("cd", {"components": COMPONENTS}, prior)
    _drive(model, rec, 2.0)
    a = model.anchor
    assert a is not None and model.probing_cycles == 5 and all(len(model.pairs[c]) == 4 for c in COMPONENTS)
    raw = model._diagrams(model.current)
    pred = model.predict(float(rec.time_s[-1]))[0]
    for c in COMPONENTS:
        g = model.change_gain(c)
        assert 0.0 <= g <= 1.0
        assert pred[c] == pytest.approx(a["y"][c] + g * (raw[c] - a["f"][c]))
    assert prior["change_gain"].keys() == set(COMPONENTS)
    assert all(0.0 <= v <= 1.0 for v in prior["change_gain"].values())
