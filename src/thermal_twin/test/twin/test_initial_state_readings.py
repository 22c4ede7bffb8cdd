"""A twin started where a recording's first readings put it (``initial_state: {readings: ...}``):
sensed nodes take the readings, hidden nodes their heat balance; calibrate on a recording that
starts warm fits the physics instead of the start-up transient; bad descriptions are refused."""
from __future__ import annotations

import copy
import pathlib

import numpy as np
import pytest

from thermal_eval.diagnose.concealed import operating_programme
from thermal_twin.calibrate.fit import calibrate
from thermal_twin.machine.schema import MachineSpecError, load_machine
from thermal_twin.physics.thermal_network import ThermalNetwork
from thermal_twin.sim.initial_state import first_readings, readings_state, start_state
from thermal_twin.sim.simulate import simulate

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"
SECTION = {"kinds": {"capacity": "fixed", "bias": "fixed", "boundary": "fixed", "gain": "fixed",
                     "conductance": {"factor": 2.0}, "source": {"factor": 2.0}}}


@pytest.fixture(scope="module")
def warm():
    """24 h of the mini mill with its spindle-head conductance x1.6 (the truth), and the part
    from 8 h on: a recording that starts warm."""
    spec = load_machine(TWIN).to_dict()
    true = copy.deepcopy(spec)
    true["links"]["spindle_head"]["conductance"] *= 1.6
    rec = simulate(true, operating_programme(spec, hours=24.0, step_s=300.0, seed=3), seed=1).to_recording()
    return true, rec, rec.slice(96, len(rec))


def test_readings_pin_the_sensed_nodes_and_hidden_nodes_take_their_heat_balance():
    spec = load_machine(TWIN).to_dict()
    m = load_machine(spec)
    net = ThermalNetwork(m)
    inputs = {n: s.default for n, s in m.inputs.items()}
    # every node sensed: the state is the readings (minus each sensor's bias, through its gain)
    sensed = {"spindle": 31.0, "head": 27.0, "column": 23.5, "table": 21.0}
    x = readings_state(net, inputs, sensed)
    assert x == pytest.approx([sensed[n] - m.sensors[n].bias for n in net.node_names], abs=1e-9)
    # head not read: it sits at the balance of its links to its neighbours under these inputs
    x2 = readings_state(net, inputs, {k: v for k, v in sensed.items() if k != "head"})
    K, Kb = net.matrices(inputs)
    rhs = Kb @ net.boundary_temperatures(inputs) + net.source_powers(inputs, 0.0)
    h = net.node_names.index("head")
    assert K[h] @ x2 == pytest.approx(rhs[h], abs=1e-6)
    assert x2[h] != pytest.approx(sensed["head"], abs=0.1)


def test_a_warm_segment_started_from_its_readings_follows_the_truth(warm):
    true, _, seg = warm
    cols = ["spindle_c", "head_c", "E_Z0T"]
    err = {}
    for mode in ("steady", "readings"):
        s = copy.deepcopy(true)
        s["initial_state"] = start_state(true, seg, mode)
        out = simulate(s, _timeline_of(seg, s), seed=1).to_recording()
        err[mode] = {c: float(np.sqrt(np.mean((_rel(out, c) - _rel(seg, c)) ** 2))) for c in cols}
    for c in cols:
        assert err["readings"][c] < 0.25 * err["steady"][c], (c, err)


def _rel(rec, c):
    v = np.asarray(rec.columns[c], dtype=float)
    return v - v[0] if c.startswith("E_") else v


def _timeline_of(rec, spec):
    # the recording's own inputs drive the twin (function-level: only this helper needs it)
    from thermal_twin.sim.inputs_timeline import timeline_from_recording
    return timeline_from_recording(load_machine(spec), rec)


def test_calibrate_from_the_readings_fits_a_warm_recording_and_writes_the_twins_own_start(warm):
    _, _, seg = warm
    got = {m: calibrate(TWIN, seg, section=SECTION, max_nfev=20, initial_state=m) for m in ("steady", "readings")}
    after = {m: r.channel_table()["E_Z0T"]["holdout_rmse_after"] for m, r in got.items()}
    assert after["readings"] < 0.2 * after["steady"], after
    est = {e.param.name: e.value for e in got["readings"].estimates}
    assert est["links.spindle_head.conductance"] == pytest.approx(8.0 * 1.6, rel=0.15)
    assert got["readings"].spec["initial_state"] == "steady"        # a run's readings are not the twin's
    assert got["readings"].measured["E_Z0T"][0] == 0.0                # displacements from the first row


def test_a_cold_recording_gives_the_same_fit_either_way(warm):
    """From rest the readings are the idle state up to their noise: the identified conductance
    and the held-out fit agree (weakly identified parameters may trade the noise differently)."""
    _, rec, _ = warm
    got = {m: calibrate(TWIN, rec, section=SECTION, max_nfev=20, initial_state=m) for m in ("steady", "readings")}
    g = {m: {e.param.name: e.value for e in r.estimates}["links.spindle_head.conductance"] for m, r in got.items()}
    assert g["readings"] == pytest.approx(g["steady"], rel=0.02)
    tables = {m: r.channel_table() for m, r in got.items()}
    for c, row in tables["steady"].items():
        assert tables["readings"][c]["holdout_rmse_after"] == pytest.approx(row["holdout_rmse_after"], abs=0.05), c


@pytest.mark.parametrize("init, why", [
    ({"readings": {"nowhere": 20.0}}, "initial_state.readings: 'nowhere' is not a sensor"),
    ({"readings": {"spindle": float("nan")}}, "initial_state.readings.spindle"),
    ({"readings": {}}, "must name at least one sensor"),
    ({"readings": {"spindle": 20.0}, "boundary": "ambient"}, "exactly one of boundary, readings"),
])
def test_a_bad_initial_state_is_refused_naming_the_field(init, why):
    spec = load_machine(TWIN).to_dict()
    spec["initial_state"] = init
    with pytest.raises(MachineSpecError, match=why.replace("(", r"\(").replace(")", r"\)")):
        load_machine(spec)


def test_a_recording_without_the_twins_sensors_cannot_start_it_from_readings(warm):
    _, _, seg = warm
    bare = seg.slice(0, len(seg))
    for c in [c for c in bare.columns if c.endswith("_c")]:
        del bare.columns[c]
    with pytest.raises(ValueError, match="has no reading of a sensor"):
        start_state(load_machine(TWIN).to_dict(), bare, "readings")
    with pytest.raises(ValueError, match="'cold' is not one of steady, readings"):
        start_state(load_machine(TWIN).to_dict(), seg, "cold")
    assert first_readings(load_machine(TWIN), seg.columns)["spindle"] == pytest.approx(
        float(np.median(np.asarray(seg.columns["spindle_c"][:5]))))
