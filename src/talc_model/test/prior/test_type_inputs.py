"""TALC with soft sensors of the machine type (TalcConfig.type_model, inputs ``twin:<node>``):
the inputs are the nominal twin's node temperatures, bad configurations are refused, the
discrepancy pole keeps the prior's input-output map, and the soft sensors' state round-trips
through TALC's persisted state (an old state without it says so)."""
import json

import numpy as np
import pytest

from talc_model.arx.model import ArxModel, ArxOrders
from talc_model.prior.talc import build_talc_prior, talc_with_prior, with_discrepancy_pole
from talc_model.talc.model import TalcModel
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate
from thermal_twin.sim.type_soft_sensors import TypeSoftSensors

NODES = ["twin:table", "twin:cradle", "twin:cradle_jet", "twin:column", "twin:c_rotor", "twin:bed"]
CFG = {"preset": "table_6_4_178h", "component_names": ["E_Y0C", "E_Z0T", "E_C0C"], "angular_components": ["E_C0C"],
       "input_names": NODES, "type_model": "nmv5000", "na_max": 1, "nb_max": 2, "nb_max_final": 2}


def _short(scenario: str, seed: int, hours: float):
    tl = make_timeline("nmv5000", scenario, seed=seed)
    keep = tl.time_s <= hours * 3600.0
    tl = type(tl)(tl.time_s[keep], {k: np.asarray(v)[keep] for k, v in tl.values.items()}, name=tl.name)
    return simulate("nmv5000", tl, seed=seed).to_recording()


def _feed(model, rec, rows):
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    inputs = {c: rec.columns[c] for c in rec.names("input")}
    for k in rows:
        model.update_inputs(float(rec.time_s[k]), {s: float(v[k]) for s, v in sensors.items()},
                            {s: float(v[k]) for s, v in inputs.items()})


@pytest.fixture(scope="module")
def recordings():
    return [_short("load-case-D", 101, 24.0), _short("load-case-A", 102, 24.0), _short("load-case-C", 103, 24.0)]


def test_the_inputs_are_the_nominal_twins_node_temperatures(recordings):
    rec = recordings[0]
    model = TalcModel(CFG)
    twin = TypeSoftSensors("nmv5000")
    _feed(model, rec, range(0, 600))
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    inputs = {c: rec.columns[c] for c in rec.names("input")}
    first = last = None
    for k in range(0, 600):
        v = twin.update(float(rec.time_s[k]), {s: float(a[k]) for s, a in sensors.items()},
                        {s: float(a[k]) for s, a in inputs.items()})
        first = first or v
        last = v
    expected = np.array([last[n] - first[n] for n in NODES])
    np.testing.assert_allclose(model._current_u(), expected, atol=1e-12)
    assert np.ptp(model.grid.u[: model.grid.n], axis=0).max() > 1.0    # the twin's nodes did move


def test_bad_configurations_name_the_field():
    with pytest.raises(ValueError, match="'input_names'.*twin:table.*'type_model' names no type"):
        TalcModel({**CFG, "type_model": ""})
    with pytest.raises(ValueError, match="'input_names'.*twin:spindle.*not soft sensors of the type 'nmv5000'"):
        TalcModel({**CFG, "input_names": ["twin:spindle", "ambient"]})
    with pytest.raises(ValueError, match="'type_model': 'no_such_machine'"):
        TalcModel({**CFG, "type_model": "no_such_machine"})


def test_the_discrepancy_pole_keeps_the_input_output_map():
    rng = np.random.default_rng(0)
    m = ArxModel(ArxOrders(1, (1, 2)), np.array([-0.1, 2.0, 0.5, -0.3]))
    u = np.cumsum(rng.normal(size=(300, 2)), axis=0)
    u[:4] = 0.0                 # a consistent start: at rest (zero outputs) before the inputs move
    p = with_discrepancy_pole(m, 0.99)
    assert p.orders == ArxOrders(2, (2, 3))
    np.testing.assert_allclose(p.simulate(u, np.zeros(3), 3)[3:], m.simulate(u, np.zeros(3), 3)[3:], atol=1e-9)
    assert sorted(np.abs(p.poles())) == pytest.approx([0.1, 0.99])


def test_a_prior_on_soft_sensors_persists_probes_and_round_trips(recordings):
    prior = build_talc_prior(recordings, CFG, machine="nmv5000")
    state = prior["talc_state"]
    for c, d in state["models"].items():   # error map (static, pole near 0) plus the discrepancy pole
        assert ArxModel.from_state(d).extra["discrepancy_pole"] == pytest.approx(np.exp(-300.0 / (23.0 * 3600)))
    run = _short("load-case-B", 7, 12.0)
    n = len(run.time_s)
    whole, first = talc_with_prior(CFG, prior), talc_with_prior(CFG, prior)
    for model in (whole, first):
        _feed(model, run, range(0, n // 2))
        model.add_measurement(float(run.time_s[n // 2 - 1]), {"E_Y0C": 1.0, "E_Z0T": -1.0, "E_C0C": 0.5}, {})
    resumed = TalcModel.from_state(json.loads(json.dumps(first.to_state(), allow_nan=True)))
    assert type(resumed) is type(whole) and resumed.soft_sensors.t_s == whole.soft_sensors.t_s
    for model in (whole, resumed):
        _feed(model, run, range(n // 2, n))
    assert resumed.predict(float(run.time_s[-1])) == whole.predict(float(run.time_s[-1]))
    old = first.to_state()
    old["soft_sensors"] = None
    again = TalcModel.from_state(old)
    assert again.soft_sensors.stepper is None
    assert "start at the type's steady state of the next instant" in again.message


def test_type_input_names_are_the_inputs_of_runs_started_from_the_prior(recordings):
    thesis = ["ambient", "ws_mwf", "c_coolant_delta", "coolant_on"]
    cfg = {**CFG, "input_names": thesis, "type_input_names": NODES}
    alone = TalcModel(cfg)                      # the thesis's protocol: its own inputs, no twin stepped
    assert alone.input_names == thesis and alone.soft_sensors is None
    prior = build_talc_prior(recordings, cfg, machine="nmv5000")
    assert prior["talc_state"]["input_names"] == NODES
    model = talc_with_prior(cfg, prior)
    assert model.input_names == NODES and model.soft_sensors is not None
    with pytest.raises(ValueError, match="'type_input_names'.*twin:nowhere"):
        TalcModel({**cfg, "type_input_names": ["twin:nowhere"]})
