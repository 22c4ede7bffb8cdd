"""Machine YAML validation: errors name the key path and the bad value; round trip."""
from __future__ import annotations

import pytest

from thermal_twin.sim.inputs_timeline import InputsTimeline, TimelineError, timeline_from_recording
from thermal_twin.machine.schema import MachineSpecError, dump_machine, load_machine, save_machine
from thermal_twin.machine.presets import preset_names
from thermal_comp_common.recording_csv import Recording
from thermal_twin.sim.simulate import simulate


def _edited(edit):
    d = load_machine("nmv5000").to_dict()
    edit(d)
    return d


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["nodes"]["table"].update(capacity=-5.0), "nodes.table.capacity: -5.0 must be > 0"),
    (lambda d: d["nodes"]["table"].update(capacity="big"), "nodes.table.capacity: 'big' is not a number"),
    (lambda d: d["links"]["table_air"].update(between=["table", "nowhere"]),
     "links.table_air.between[1]: 'nowhere' is not a node or boundary"),
    (lambda d: d["links"]["table_air"]["varies_with"].update(door=dict(per_unit=1.0)),
     "links.table_air.varies_with.door: 'door' is not a declared input"),
    (lambda d: d["links"]["table_air"].update(conductance=-1), "links.table_air.conductance: -1.0 must be >= 0"),
    (lambda d: d["sources"]["c_motor_losses"].update(node="spindle"),
     "sources.c_motor_losses.node: 'spindle' is not a node"),
    (lambda d: d["sensors"]["ambient"].update(of="outside"), "sensors.ambient.of: 'outside' is not a node or boundary"),
    (lambda d: d["sensors"]["ambient"].update(colour="red"), "sensors.ambient.colour: 'red' is not a known key"),
    (lambda d: d["errors"]["E_Y0C"].update(unit="mm"), "errors.E_Y0C.unit: 'mm' must be one of"),
    (lambda d: d["errors"]["E_Y0C"]["terms"].update(spindle=1.0), "errors.E_Y0C.terms: 'spindle' is not a node"),
    (lambda d: d["inputs"].update(ambient_c=dict(default=0)), "inputs.ambient_c: 'ambient_c' clashes"),
    (lambda d: d["units"].update(temperature="K"), "units.temperature: 'K' must be 'degC'"),
    (lambda d: d.update(initial_state="hot"), "initial_state: 'hot' must be 'steady'"),
    (lambda d: d["boundaries"]["cooler"].update(temperature="cooler_setpoint"),
     "boundaries.cooler.temperature: 'cooler_setpoint' is not a declared input"),
])
def test_validation_names_key_and_value(edit, message):
    with pytest.raises(MachineSpecError) as exc:
        load_machine(_edited(edit))
    assert message in str(exc.value)


def test_isolated_node_is_rejected_when_simulating():
    d = _edited(lambda d: d["nodes"].update(loose={"capacity": 100.0}))
    with pytest.raises(MachineSpecError, match="nodes.loose: 'loose' has no link path"):
        simulate(d, InputsTimeline.constant(600, 60))


def test_yaml_errors_name_the_file(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_text("name: [unclosed\n")
    with pytest.raises(MachineSpecError, match="m.yaml: not valid YAML"):
        load_machine(p)
    p.write_text(dump_machine(load_machine("nmv5000")).replace("capacity: 160000.0", "capacity: 0"))
    with pytest.raises(MachineSpecError, match=r"m.yaml: nodes.table.capacity: 0.0 must be > 0"):
        load_machine(p)


@pytest.mark.parametrize("name", preset_names())
def test_presets_round_trip_through_yaml(name, tmp_path):
    m = load_machine(name)
    save_machine(m, tmp_path / "copy.yaml")
    again = load_machine(tmp_path / "copy.yaml")
    assert again.to_dict() == m.to_dict()
    # one item per line: editing one link changes one line of the file
    text = (tmp_path / "copy.yaml").read_text().splitlines()
    d = m.to_dict()
    first_link = next(iter(d["links"]))
    d["links"][first_link]["conductance"] = 123.0
    save_machine(d, tmp_path / "edited.yaml")
    changed = [a for a, b in zip(text, (tmp_path / "edited.yaml").read_text().splitlines()) if a != b]
    assert len(changed) == 1 and first_link in changed[0]


def test_scientific_notation_is_a_number():
    m = load_machine("name: m\nboundaries: {a: {temperature: 20}}\nnodes: {n: {capacity: 2.5e4}}\n"
                     "links: {l: {between: [n, a], conductance: 1e1}}\n")
    assert m.nodes["n"].capacity == 25000.0 and m.links["l"].conductance == 10.0


def test_timeline_checks_inputs_against_the_machine():
    m = load_machine("nmv5000")
    with pytest.raises(TimelineError, match="input 'spindle_rpm' is not declared by machine 'nmv5000'"):
        simulate(m, InputsTimeline.constant(600, 60, spindle_rpm=100))
    with pytest.raises(TimelineError, match=r"input 'c_speed_rpm': 5000.0 at t=0.0 s is outside \[0.0, 1200.0\]"):
        simulate(m, InputsTimeline.constant(600, 60, c_speed_rpm=5000))


def test_timeline_from_a_recording_uses_the_ambient_sensor_when_true_ambient_is_missing():
    import numpy as np
    m = load_machine("spindle-stand")
    t = np.arange(0, 600.0, 60.0)
    rec = Recording(t, {"spindle_rpm": np.full(len(t), 1000.0), "t11_c": np.linspace(25, 26, len(t))})
    tl = timeline_from_recording(m, rec)
    assert np.allclose(tl.values["ambient_degc"], rec.columns["t11_c"])
    assert np.allclose(tl.values["spindle_rpm"], 1000.0)


@pytest.mark.parametrize("name", preset_names())
def test_presets_place_every_sensor_for_viewers(name):
    m = load_machine(name)
    assert all(s.position_mm is not None and len(s.position_mm) == 3 for s in m.sensors.values())
    d = m.to_dict()
    sid = next(iter(d["sensors"]))
    d["sensors"][sid]["position_mm"] = [1.0, "a", 3.0]
    with pytest.raises(MachineSpecError, match=rf"sensors.{sid}.position_mm: \[1.0, 'a', 3.0\] must be \[x, y, z\]"):
        load_machine(d)
