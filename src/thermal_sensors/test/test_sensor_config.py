"""Sensor YAML validation: every mistake names the key path and the value."""
from __future__ import annotations

import pytest

from thermal_sensors.sensor_config import (SensorConfigError, load_sensor_config,
                                           parse_sensor_config, require_modbus)

GOOD = {
    "max_age_s": 30,
    "sensors": [
        {"id": "ambient", "range_degc": [-10, 50], "stale_after_s": 600,
         "calibration": {"offset_degc": 0.2, "gain": 0.998},
         "modbus": {"module": "rtd1", "address": 0}},
        {"id": "nozzle", "channel": "mwf_nozzle", "modbus": {"module": "rtd1", "address": 1,
                                                            "type": "uint16", "scale": 0.01}},
    ],
    "modbus": {"modules": [{"name": "rtd1", "port": 1502, "unit_id": 3}]},
}


def test_good_config_parses_with_defaults():
    c = parse_sensor_config(GOOD)
    assert c.sensor_ids == ("ambient", "nozzle")
    assert c.sensors[1].csv_column == "mwf_nozzle_c" and c.sensors[0].csv_column == "ambient_c"
    assert c.sensors[0].gain_offset.gain == 0.998 and c.sensors[1].range_degc == (-50.0, 150.0)
    assert c.sensors[1].modbus.effective_fault_raw == 65535
    assert c.module("rtd1").timeout_s == 0.5 and c.module("rtd1").transport == "tcp"
    require_modbus(c)


def test_section_inside_a_cell_file_is_found(tmp_path):
    import yaml
    p = tmp_path / "cell.yaml"
    p.write_text(yaml.safe_dump({"temperature_publisher": GOOD}))
    assert load_sensor_config(p).sensor_ids == ("ambient", "nozzle")


def _with(path: str, value):
    import copy
    doc = copy.deepcopy(GOOD)
    keys = path.split(".")
    node = doc
    for k in keys[:-1]:
        node = node[int(k)] if k.isdigit() else node[k]
    last = keys[-1]
    if value is KeyError:
        del node[last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return doc


@pytest.mark.parametrize("path,value,message", [
    ("sensors", [], "sensors: [] must be a non-empty list"),
    ("sensors.0.range_degc", [50, 10], "sensors[0].range_degc: [50, 10]"),
    ("sensors.0.range_degc", "hot", "sensors[0].range_degc: 'hot'"),
    ("sensors.0.stale_after_s", -1, "sensors[0].stale_after_s: -1.0 is below the minimum"),
    ("sensors.0.calibration.gain", 0, "sensors[0].calibration.gain: 0"),
    ("sensors.0.calibration.offset", 1, "sensors[0].calibration.offset: unknown key"),
    ("sensors.1.id", "ambient", "sensors[1].id: 'ambient' duplicates sensors[0]"),
    ("sensors.1.modbus.type", "float32", "sensors[1].modbus.type: 'float32' is not one of"),
    ("sensors.1.modbus.address", 70000, "sensors[1].modbus.address: 70000 is outside 0..65535"),
    ("sensors.1.modbus.module", "rtd9", "sensors[1].modbus.module: 'rtd9' is not a module"),
    ("sensors.1.modbus.scale", 0, "sensors[1].modbus.scale: 0 must not be 0"),
    ("sensors.0.id", KeyError, "sensors[0].id: missing"),
    ("max_age_s", "long", "max_age_s: 'long' is not a finite number"),
    ("modbus.modules.0.transport", "udp", "modbus.modules[0].transport: 'udp' is not one of"),
    ("modbus.modules.0.unit_id", 300, "modbus.modules[0].unit_id: 300 is outside 0..247"),
    ("modbus.modules.0.timeout_s", 0, "modbus.modules[0].timeout_s: 0.0 must be > 0"),
    ("modbus.modules.0.reconnect_max_s", 0.1, "modbus.modules[0].reconnect_max_s: 0.1 is below"),
    ("modbus.modules.0.port", True, "modbus.modules[0].port: True is not an integer"),
])
def test_bad_values_name_the_key(path, value, message):
    with pytest.raises(SensorConfigError) as err:
        parse_sensor_config(_with(path, value), source="cell.yaml")
    assert message in str(err.value) and str(err.value).startswith("cell.yaml: ")


def test_rtu_needs_a_serial_port_and_units_are_unique_per_line():
    doc = _with("modbus.modules", [{"name": "rtd1", "transport": "rtu"}])
    with pytest.raises(SensorConfigError, match=r"modules\[0\]\.serial_port: missing"):
        parse_sensor_config(doc)
    doc = _with("modbus.modules", [{"name": "rtd1", "transport": "rtu", "serial_port": "/dev/ttyUSB0"},
                                   {"name": "rtd2", "transport": "rtu", "serial_port": "/dev/ttyUSB0"}])
    with pytest.raises(SensorConfigError, match=r"modules\[1\]\.unit_id: 1 is already used"):
        parse_sensor_config(doc)
    doc = _with("modbus.modules", [{"name": "rtd1", "transport": "rtu", "serial_port": "/dev/ttyUSB0"},
                                   {"name": "rtd1", "transport": "rtu", "serial_port": "/dev/ttyUSB1"}])
    with pytest.raises(SensorConfigError, match=r"modules\[1\]\.name: 'rtd1' duplicates modules\[0\]"):
        parse_sensor_config(doc)


def test_modbus_source_requires_a_register_per_sensor():
    doc = _with("sensors.1.modbus", KeyError)
    with pytest.raises(SensorConfigError, match=r"sensors\[1\]\.modbus: missing for sensor 'nozzle'"):
        require_modbus(parse_sensor_config(doc))


def test_file_errors(tmp_path):
    with pytest.raises(SensorConfigError, match="no such sensor config file"):
        load_sensor_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensors: [id: x\n")
    with pytest.raises(SensorConfigError, match="not valid YAML"):
        load_sensor_config(bad)
