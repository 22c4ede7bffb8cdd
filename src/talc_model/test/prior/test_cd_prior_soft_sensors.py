"""The characteristic-diagram prior on the machine type's soft sensors (CdConfig.type_model /
type_inputs): the forward selection on the held-out programme picks them, the model reads the
machine inputs under MachineState names as under a replay's, bad configurations name the key,
and the soft sensors' state resumes with the model (an old state without it says so).
Figures: docs/prior.md, "Characteristic diagrams"."""
import json

import numpy as np
import pytest

from talc_model.adaptive_model import model_from_state
from talc_model.cd.model import CdModelError, CharacteristicDiagramModel
from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.cd import CdPriorModel, build_cd_prior
from talc_model.type_inputs import load_soft_sensors
from thermal_comp_common.machine_state_fields import message_input_name
from thermal_twin.machine.instance import machine_instance
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

COMPONENTS = ["E_X0C", "E_Y0C"]
SOFT = load_soft_sensors("nmv5000", [], "test", "'type_inputs'").names


def _sim(machine, scenario, seed, hours):
    return simulate(machine, make_timeline("nmv5000", scenario, hours=hours, seed=seed), seed=seed).to_recording()


@pytest.fixture(scope="module")
def prior():
    recs = [_sim("nmv5000", s, 101 + i, 24.0) for i, s in enumerate(["load-case-A", "load-case-B", "load-case-C"])]
    return build_cd_prior(recs, {"components": COMPONENTS, "type_model": "nmv5000", "type_inputs": SOFT},
                          machine="nmv5000", sources=["a", "b", "c"])


@pytest.fixture(scope="module")
def run():
    return _sim(machine_instance("nmv5000", 1), "load-case-D", 0, 6.0)


def _drive(model, rec, rows, rename=lambda n: n):
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    inputs = {rename(c): rec.columns[c] for c in rec.names("input")}
    out = []
    for k in rows:
        t = float(rec.time_s[k])
        model.update_inputs(t, {s: float(v[k]) for s, v in sensors.items()},
                            {s: float(v[k]) for s, v in inputs.items()})
        if model.probe_due(t):
            model.add_measurement(t, {c: float(rec.columns[c][k] - rec.columns[c][0]) for c in COMPONENTS}, {})
        out.append(model.predict(t)[0])
    return out


def test_the_held_out_selection_picks_the_types_soft_sensors(prior):
    assert prior["cd_config"]["type_inputs"] == SOFT and prior["cd_config"]["type_model"] == "nmv5000"
    assert prior["cd_config"]["extrapolate_type_inputs"] is True          # the prior's default with soft sensors
    for c in COMPONENTS:
        assert prior["input_names"][c][0] == f"twin:{c}"       # the type's own prediction of the error first
        assert prior["validation_rms"][c] < 0.1                  # the nominal type: its error map, exactly
    model = model_from_prior("cd", {"components": COMPONENTS}, prior)
    assert isinstance(model, CdPriorModel) and model.soft_sensors is not None
    assert model.candidate_names == prior["candidate_names"]


def test_soft_sensors_read_machine_state_names_as_replay_names(prior, run):
    replay = model_from_prior("cd", {"components": COMPONENTS}, prior)
    graph = model_from_prior("cd", {"components": COMPONENTS}, prior)
    renamed = {n: message_input_name(n) for n in run.names("input")}
    assert renamed["c_speed_rpm"] == "C_axis_rpm" and renamed["coolant_temp_degc"] == "coolant_temperature_degc"
    a = _drive(replay, run, range(len(run)))
    b = _drive(graph, run, range(len(run)), rename=lambda n: renamed[n])
    assert a == b and replay.probing_cycles == graph.probing_cycles > 0
    assert graph.soft_sensors.held_counts == {n: 0 for n in graph.soft_sensors.input_names}
    blind = model_from_prior("cd", {"components": COMPONENTS}, prior)   # no machine inputs at all: held, listed
    c = _drive(blind, run, range(len(run)), rename=lambda n: f"unknown_{n}")
    assert c != a and blind.soft_sensors.held_counts["c_speed_rpm"] == len(run)
    assert "c_speed_rpm (type twin input, held)" in blind.status(float(run.time_s[-1])).excluded_sensor_ids


def test_the_soft_sensors_resume_with_the_model(prior, run):
    model = model_from_prior("cd", {"components": COMPONENTS}, prior)
    half = len(run) // 2
    _drive(model, run, range(half))
    state = json.loads(json.dumps(model.to_state()))
    assert state["soft_sensors"]["t_s"] == float(run.time_s[half - 1])
    back = model_from_state(state)
    assert isinstance(back, CdPriorModel) and back.soft_sensors is not model.soft_sensors
    assert _drive(back, run, range(half, len(run))) == _drive(model, run, range(half, len(run)))
    old = {k: v for k, v in state.items() if k != "soft_sensors"}   # saved before the soft sensors
    assert "they start at the type's steady state" in model_from_state(old).message


def test_the_default_prior_has_the_types_soft_sensors_and_extrapolates_along_them_only():
    recs = [_sim("nmv5000", s, 101 + i, 12.0) for i, s in enumerate(["load-case-A", "load-case-B"])]
    p = build_cd_prior(recs, {"components": ["E_Y0C", "E_R0T"]}, machine="nmv5000")
    assert p["cd_config"]["type_model"] == "nmv5000" and p["cd_config"]["type_inputs"] == SOFT
    assert p["cd_config"]["extrapolate_type_inputs"] is True
    for c in ("E_Y0C", "E_R0T"):
        flags = p["cds"][c]["extrapolate"]
        assert flags == [n.startswith("twin:") for n in p["input_names"][c]] and any(flags)
    with pytest.raises(PriorError, match="no machine type for the soft sensors"):
        build_cd_prior(recs, {"components": ["E_Y0C"]})


def test_bad_soft_sensor_configurations_name_the_key():
    with pytest.raises(CdModelError, match="'type_inputs'.*'type_model' names no type"):
        CharacteristicDiagramModel({"type_inputs": ["twin:table"]})
    with pytest.raises(ValueError, match=r"cd config 'type_inputs': \['twin:nope'\] are not soft sensors"):
        CharacteristicDiagramModel({"type_model": "nmv5000", "type_inputs": ["twin:nope"]})
    with pytest.raises(ValueError, match="cd config 'type_model': 'no-such-type'"):
        CharacteristicDiagramModel({"type_model": "no-such-type", "type_inputs": ["twin:table"]})
    plain = CharacteristicDiagramModel({"type_model": "nmv5000"})          # a type without soft inputs: not stepped
    assert plain.soft_sensors is None and plain.level_columns == 0


def test_temperatures_only_prior_is_unchanged_by_the_option():
    recs = [_sim("nmv5000", s, 101 + i, 12.0) for i, s in enumerate(["load-case-A", "load-case-B"])]
    p = build_cd_prior(recs, {"components": ["E_Y0C"], "type_inputs": []}, machine="nmv5000")
    assert not any(n.startswith("twin:") for n in p["candidate_names"])
    assert model_from_prior("cd", {"components": ["E_Y0C"]}, p).soft_sensors is None
    assert np.isfinite(p["validation_rms"]["E_Y0C"])
