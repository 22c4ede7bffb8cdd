"""The characteristic-diagram prior: built from nominal runs with the CD model's own inputs,
the model compensates from the first instant with it, adapts by load-case updates, and a saved
state resumes with its prior."""
import json

import numpy as np
import pytest

from talc_model.adaptive_model import PHASE_COMPENSATION, model_from_state
from talc_model.cd.model import CharacteristicDiagramModel
from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.cd import CdPriorModel, build_cd_prior, cd_inputs, change_gain
from talc_model.cd.model import CdConfig
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

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
    with pytest.raises(PriorError, match="min_q_prod_pct 100.0"):
        CdPriorModel({"components": COMPONENTS}, {**prior, "adaptation": {**prior["adaptation"], "min_q_prod_pct": 100.0}})


def _drive(model, rec, until_h):
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    inputs = {c: rec.columns[c] for c in rec.names("input")}
    preds = []
    for k, t in enumerate(rec.time_s):
        if t > until_h * 3600.0:
            break
        if model.t_input is not None and t <= model.t_input:     # driven that far already: continue after it
            continue
        model.update_inputs(float(t), {s: float(v[k]) for s, v in sensors.items()},
                            {s: float(v[k]) for s, v in inputs.items()})
        if model.probe_due(float(t)):
            model.add_measurement(float(t), {c: float(rec.columns[c][k] - rec.columns[c][0]) for c in COMPONENTS}, {})
        preds.append(model.predict(float(t))[0]["E_Y0C"])
    return preds


def test_compensates_from_the_first_instant_adapts_and_resumes(prior):
    rec = simulate("nmv5000", make_timeline("nmv5000", "talc-178h-dry", hours=12.0, seed=0), seed=0).to_recording()
    with_updates = {**prior, "adaptation": {**prior["adaptation"], "load_case_updates": True, "check_s": 4 * 3600.0,
                                            "interval_by_gain": False}}
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


def _state_file(tmp_path, model):
    path = tmp_path / "model_state.json"
    path.write_text(json.dumps(model.to_state()))
    return path


def test_another_machines_adapted_cd_state_is_a_prior_a_run_starts_from(prior, tmp_path):
    from talc_model.prior.cd import cd_prior_from_state
    from thermal_twin.machine.instance import machine_instance
    from thermal_twin.machine.schema import load_machine
    src = model_from_prior("cd", {"components": COMPONENTS}, prior)
    rec = simulate(machine_instance("nmv5000", 2), make_timeline("nmv5000", "load-case-B", hours=12.0, seed=7),
                   seed=7).to_recording()
    _drive(src, rec, 12.0)                                    # past the 8-h check: measured pairs
    assert len(src.pairs["E_Y0C"]) >= src.min_pairs
    state = json.loads(_state_file(tmp_path, src).read_text())       # as saved (thermal-comp prior --from-state: thermal_comp's test)
    derived = cd_prior_from_state(state, machine="nmv5000", sensors=load_machine("nmv5000").sensor_ids)
    assert derived["model_kind"] == "cd" and derived["sources"] == ["persisted model state"]
    assert derived["change_gain"] == {c: src.change_gain(c) for c in COMPONENTS}     # its measured gain
    assert len(derived["anchors"]["u"]) == len(prior["anchors"]["u"]) + len(src.new_u)
    run = model_from_prior("cd", {"components": COMPONENTS}, derived)
    other = simulate(machine_instance("nmv5000", 1), make_timeline("nmv5000", "load-case-A", hours=2.0, seed=8),
                     seed=8).to_recording()
    preds = _drive(run, other, 2.0)
    assert isinstance(run, CdPriorModel) and run.phase == PHASE_COMPENSATION and np.any(np.abs(preds[1:]) > 0)
    assert run.change_gain("E_Y0C") == src.change_gain("E_Y0C") or len(run.pairs["E_Y0C"]) >= run.min_pairs


def test_a_plain_cd_state_becomes_a_prior_on_temperature_deltas(tmp_path):
    from talc_model.prior.cd import cd_prior_from_state
    rec = simulate("nmv5000", make_timeline("nmv5000", "load-case-A", hours=8.0, seed=9), seed=9).to_recording()
    plain = CharacteristicDiagramModel({"components": COMPONENTS, "min_calibration_s": 5 * 3600.0})
    _drive(plain, rec, 8.0)
    assert plain.phase == PHASE_COMPENSATION and not plain.new_u      # fitted, no probe since
    derived = cd_prior_from_state(json.loads(_state_file(tmp_path, plain).read_text()), machine="nmv5000",
                                  sensors=plain.sensor_names)
    u = np.asarray(plain.base_u)
    du = u.copy()
    du[:, :plain.level_columns] -= u[0, :plain.level_columns]
    for c in COMPONENTS:                                      # the same diagrams, on deltas from its first probe
        from talc_model.cd.diagram import CharacteristicDiagram
        cols = plain.inputs[c]
        shifted = CharacteristicDiagram.from_state(derived["cds"][c]).predict(du[:, cols])
        assert np.allclose(shifted, plain.base[c].predict(u[:, cols]), atol=1e-6)
    assert isinstance(model_from_prior("cd", {"components": COMPONENTS}, derived), CdPriorModel)


def test_from_state_refuses_other_kinds_calibrating_models_and_other_types_channels(prior):
    from talc_model.prior.cd import cd_prior_from_state
    with pytest.raises(PriorError, match="'kind' is 'talc'"):
        cd_prior_from_state({"kind": "talc"})
    calibrating = CharacteristicDiagramModel({"components": COMPONENTS})
    calibrating.update_inputs(0.0, {"a": 20.0}, {})
    with pytest.raises(PriorError, match="still in calibration"):
        cd_prior_from_state(json.loads(json.dumps(calibrating.to_state())))
    state = json.loads(json.dumps(model_from_prior("cd", {"components": COMPONENTS}, prior).to_state()))
    with pytest.raises(PriorError, match="another machine type"):
        cd_prior_from_state(state, sensors=["ambient", "cutting_oil"])     # the lathe's channels


def test_interval_from_gain_probes_more_often_with_a_low_gain():
    from talc_model.prior.cd import interval_from_gain
    lags = [0.5, 1.0, 2.0, 4.0]
    # a drift the diagrams predict exactly: yy = yp = pp, growing as the lag squared
    st = {"E": {"lags_h": lags, "yy": [l * l for l in lags], "yp": [l * l for l in lags], "pp": [l * l for l in lags]}}
    assert interval_from_gain(st, {"E": 1.0}, 0.5, 4.0) == 4.0         # the predicted change is the change
    assert interval_from_gain(st, {"E": 0.0}, 0.5, 4.0) == 0.5         # hold: as often as the check phase
    assert interval_from_gain(st, {"E": 0.5}, 0.5, 4.0) == 1.0         # (1 - g)^2 l^2 <= 0.25 up to l = 1
    assert interval_from_gain(st, {"E": 0.0}, 0.5, 4.0, noise={"E": 2.0}) == 2.0   # drift below the probe noise
    assert interval_from_gain(st, {"E": 1.0}, 0.5, 3.0) == 2.0         # never beyond the update interval
    assert interval_from_gain(st, {}, 0.5, 4.0) == 4.0                 # no gain of it: does not constrain


def test_the_interval_after_the_check_follows_the_measured_gain(prior):
    rec = simulate("nmv5000", make_timeline("nmv5000", "talc-178h-dry", hours=12.0, seed=0), seed=0).to_recording()
    hold = {**prior, "change_gain": {c: 0.0 for c in COMPONENTS},
            "adaptation": {**prior["adaptation"], "min_pairs": 99, "min_q_prod_pct": 0.0, "interval_by_gain": True}}
    model = model_from_prior("cd", {"components": COMPONENTS}, hold)
    assert model.interval_by_gain
    _drive(model, rec, 12.0)
    assert model.probing_cycles == 25                          # gain 0: every 30 min after the check too
    floored = model_from_prior("cd", {"components": COMPONENTS},
                               {**hold, "adaptation": {**hold["adaptation"], "min_q_prod_pct": 97.0}})
    _drive(floored, rec, 12.0)
    # the check phase's 16 probings in 8 h leave Q_prod at 94.7 %: the productivity floor holds the
    # longest interval (4 h) until the run is back above 97 %, whatever the gain asks
    assert floored.probing_cycles == 17 + 1
    assert floored._productivity_floor_s() > floored.config.update_probe_interval_s
    fixed = model_from_prior("cd", {"components": COMPONENTS},
                             {**hold, "adaptation": {**hold["adaptation"], "interval_by_gain": False}})
    _drive(fixed, rec, 12.0)
    assert fixed.probing_cycles == 17 + 1                      # 0-8 h every 30 min, then 12 h
