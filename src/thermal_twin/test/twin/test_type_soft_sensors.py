"""thermal_twin.sim.type_soft_sensors: the nominal twin stepped online from a model's inputs
reproduces the twin's own run (to sensor noise), under both input naming conventions, holds
missing inputs, refuses time going back and resumes from its persisted state."""
import json
import math
import types

import numpy as np
import pytest

from thermal_comp_common.machine_inputs import machine_state_inputs
from thermal_comp_common.machine_state_fields import machine_state_fields, message_input_name
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate
from thermal_twin.sim.type_soft_sensors import SoftSensorError, TypeSoftSensors


@pytest.fixture(scope="module")
def run():
    """48 h of load-case-D (speeds, MWF switching, a swinging hall) on the NOMINAL twin."""
    tl = make_timeline("nmv5000", "load-case-D", seed=3)
    keep = tl.time_s <= 48 * 3600.0
    tl = type(tl)(tl.time_s[keep], {k: np.asarray(v)[keep] for k, v in tl.values.items()}, name=tl.name)
    return simulate("nmv5000", tl, seed=3)


def _instants(result, message_names=False):
    rec = result.to_recording()
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    inputs = {c: rec.columns[c] for c in rec.names("input") if c != "ambient_degc"}   # a real cell has no true hall
    for k, t in enumerate(rec.time_s):
        temps = {s: float(v[k]) for s, v in sensors.items()}
        state = {s: float(v[k]) for s, v in inputs.items()}
        if message_names:     # the graph's path: MachineState message -> the model's flat inputs
            msg = types.SimpleNamespace(**machine_state_fields(state), axis_names=[], axis_positions=[],
                                        machine_busy_probing=False)
            state = machine_state_inputs(msg)
        yield float(t), temps, state


def _replay(result, sensors=None, message_names=False):
    sensors = sensors or TypeSoftSensors("nmv5000")
    return np.array([list(sensors.update(t, temps, state).values())
                     for t, temps, state in _instants(result, message_names)]), sensors


def test_replaying_the_nominal_twin_reproduces_its_nodes_and_errors(run):
    out, sensors = _replay(run)
    n = len(run.machine.nodes)
    assert sensors.names[:n] == [f"twin:{x}" for x in run.machine.nodes]
    assert sensors.names[n:] == [f"twin:{e}" for e in run.errors]
    # the hall comes from the ambient sensor, not the true hall: noise 0.03 K (the largest of ~3,000
    # draws about 0.11 K), half its 0.0625 K step, a 60 s lag; the air node follows it within minutes
    assert np.abs(out[:, :n] - run.node_temperatures).max() < 0.15
    errors = np.column_stack([run.errors[e] for e in run.errors])
    assert np.ptp(errors, axis=0).min() > 5.0          # the run does move every error component
    # errors are deltas from the start: the first ambient reading (one noisy, quantised sample) sets
    # the reference steady state, so they differ by a near-constant offset within 2 % of their range
    diff = np.abs(out[:, n:] - errors).max(axis=0)
    assert np.all(diff < 0.02 * np.ptp(errors, axis=0)) and diff.max() < 0.6
    assert sum(sensors.held_counts.values()) == 0


def test_message_names_give_the_same_soft_sensors(run):
    assert message_input_name("c_speed_rpm") == "C_axis_rpm"
    assert message_input_name("coolant_temp_degc") == "coolant_temperature_degc"
    assert message_input_name("coolant_on") == "coolant_on"
    assert message_input_name("x_w") == "x_power_w"
    twin_names, _ = _replay(run)
    msg_names, sensors = _replay(run, message_names=True)
    np.testing.assert_allclose(msg_names, twin_names, rtol=0, atol=1e-9)
    assert sum(sensors.held_counts.values()) == 0


def test_missing_or_nan_inputs_hold_the_last_value_and_are_counted():
    a, b = TypeSoftSensors("nmv5000"), TypeSoftSensors("nmv5000")
    temps = {"ambient": 21.0}
    wet = {"c_speed_rpm": 600.0, "coolant_on": 1.0, "coolant_temp_degc": 26.0}
    for sensors in (a, b):
        sensors.update(0.0, temps, wet)
    for k in range(1, 30):
        va = a.update(60.0 * k, temps, wet)
        gap = {"c_speed_rpm": 600.0, "coolant_on": 1.0, "coolant_temp_degc": math.nan} if k % 2 else \
            {"c_speed_rpm": 600.0, "coolant_on": 1.0}
        vb = b.update(60.0 * k, {"ambient": math.nan} if k == 5 else temps, gap)
        assert vb == va
    assert b.held_counts["coolant_temp_degc"] == 29 and b.held_counts["ambient_degc"] == 1
    assert b.held_now == ["coolant_temp_degc"]
    assert sum(a.held_counts.values()) == 0
    with pytest.raises(SoftSensorError, match="time 10.0 goes back"):
        b.update(10.0, temps, wet)
    with pytest.raises(SoftSensorError, match="'c_speed_rpm'.*'fast' is not a number"):
        b.update(2000.0, temps, {"c_speed_rpm": "fast"})


def test_a_restored_state_resumes_where_the_twin_was(run):
    instants = list(_instants(run))
    half = len(instants) // 2
    whole = TypeSoftSensors("nmv5000")
    first = TypeSoftSensors("nmv5000")
    for t, temps, state in instants[:half]:
        whole.update(t, temps, state)
        first.update(t, temps, state)
    resumed = TypeSoftSensors("nmv5000")
    resumed.restore(json.loads(json.dumps(first.to_state())))
    for t, temps, state in instants[half:]:
        assert resumed.update(t, temps, state) == whole.update(t, temps, state)
    with pytest.raises(SoftSensorError, match="'machine' 'swiss_lathe'"):
        resumed.restore({**first.to_state(), "machine": "swiss_lathe"})


def test_a_biased_hall_sensor_of_the_twin_is_read_backwards():
    """A unit twin that says its hall sensor reads 0.6 K high feeds the boundary 0.6 K lower."""
    from thermal_twin.machine.schema import load_machine     # this test only
    spec = load_machine("nmv5000").to_dict()
    spec["sensors"]["ambient"]["bias"] = 0.6
    plain, biased = TypeSoftSensors("nmv5000"), TypeSoftSensors(spec)
    temps = {"ambient": 21.6, "ws_mwf": 22.0, "c_coolant_delta": 0.0, "c_motor_internal": 22.0}
    plain.update(0.0, temps, {})
    biased.update(0.0, temps, {})
    assert plain.last_inputs["ambient_degc"] == pytest.approx(21.6)
    assert biased.last_inputs["ambient_degc"] == pytest.approx(21.0)
