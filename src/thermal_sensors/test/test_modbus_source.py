"""The Modbus path against the RTD emulator: scaling, signedness, silence, reconnect."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from thermal_sensors.modbus_register_map import decode_register, encode_temperature, plan_reads
from thermal_sensors.modbus_source import ModbusSource
from thermal_sensors.rtd_emulator import RtdEmulator
from thermal_sensors.sensor_config import ModbusRegister, load_sensor_config, parse_sensor_config
from thermal_sensors.sensor_status import SensorStatus
from thermal_sensors.temperature_frame import TemperatureFrameBuilder

from sensor_test_data import sensors_yaml, ports  # noqa: F401 (fixture)


def wait_for(condition, deadline_s: float = 10.0, step_s: float = 0.02):
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(step_s)
    return condition()


INT16 = ModbusRegister(module="m", address=0, type="int16", scale=0.1)
UINT16_K = ModbusRegister(module="m", address=0, type="uint16", scale=0.01, offset_degc=-273.15)


@pytest.mark.parametrize("word,reg,expected", [
    (253, INT16, 25.3),              # tenths of degC, as the TECMT modules sent them
    (0xFF85, INT16, -12.3),          # two's complement: -123
    (0x8001, INT16, -3276.7),
    (0xFF85, ModbusRegister(module="m", address=0, type="uint16", scale=0.1), 6541.3),  # same word unsigned: 65413
    (29815, UINT16_K, 25.0),  # kelvin in hundredths
])
def test_decode_scaling_and_signedness(word, reg, expected):
    assert decode_register(word, reg) == pytest.approx(expected, abs=1e-9)


def test_fault_code_decodes_to_nan_and_encoding_never_aliases_it():
    assert math.isnan(decode_register(0x8000, INT16))           # default int16 fault -32768
    assert math.isnan(decode_register(0xFFFF, UINT16_K))        # default uint16 fault 65535
    assert encode_temperature(float("nan"), INT16) == 0x8000
    assert encode_temperature(-1e6, INT16) == 0x8001            # saturates one count inside
    assert encode_temperature(1e6, INT16) == 0x7FFF
    assert encode_temperature(1e6, UINT16_K) == 0xFFFE
    for v in (-40.0, -0.1, 0.0, 0.1, 21.7, 149.9):
        assert decode_register(encode_temperature(v, INT16), INT16) == pytest.approx(v, abs=1e-9)
    custom = ModbusRegister(module="m", address=0, type="int16", scale=0.1, fault_raw=32767)
    assert math.isnan(decode_register(32767, custom)) and decode_register(0x8000, custom) == -3276.8
    with pytest.raises(ValueError, match="65536"):
        decode_register(65536, INT16)


def test_reads_are_grouped_per_module_and_register_kind(tmp_path, ports):
    cfg = parse_sensor_config({
        "sensors": [{"id": f"s{a}", "modbus": {"module": "m", "address": a}} for a in (0, 1, 2, 30, 3)]
        + [{"id": "h", "modbus": {"module": "m", "address": 1, "register": "holding"}}],
        "modbus": {"modules": [{"name": "m", "port": ports[0]}]}})
    reads = sorted(plan_reads(cfg), key=lambda r: (r.register, r.start))
    assert [(r.register, r.start, r.count) for r in reads] == [("holding", 1, 1), ("input", 0, 4),
                                                              ("input", 30, 1)]
    assert dict(reads[1].targets) == {0: 0, 1: 1, 2: 2, 4: 3}


@pytest.fixture
def setup(tmp_path, ports):
    path = tmp_path / "sensors.yaml"
    path.write_text(sensors_yaml(ports))
    config = load_sensor_config(path)
    emu = RtdEmulator(config)
    emu.start()
    emu.set_temperatures({"ambient": 21.4, "spindle": 30.2, "stuck": 24.3, "hot": 55.5, "cold": -12.5})
    source = ModbusSource(config)
    yield config, emu, source
    source.close()
    emu.stop()


def test_silent_module_fails_only_its_sensors_within_the_timeout(setup):
    config, emu, source = setup
    builder = TemperatureFrameBuilder(config)
    source.poll_once()
    assert list(builder.build(source.sample(1.0)).status) == [SensorStatus.OK] * 5

    emu.set_silent("rtd_b")
    source.poll_once()        # returns after the read timeout (timing: `thermal-comp bench sensors`)
    frame = builder.build(source.sample(2.0))
    assert list(frame.status) == [0, 0, 3, 3, 0]
    assert np.isnan(frame.temperatures_degc[2:4]).all()
    assert "rtd_b" in frame.reasons[2] and "did not answer" in frame.reasons[2]

    # while it stays silent the next sample must not resurrect the old value as ok
    source.poll_once()
    assert list(builder.build(source.sample(3.0)).status)[2:4] == [3, 3]

    emu.set_silent("rtd_b", False)
    assert wait_for(lambda: (source.poll_once(), builder.build(source.sample(4.0)).status[2] == 0)[1])
    frame = builder.build(source.sample(5.0))
    assert list(frame.status) == [0] * 5
    assert frame.temperatures_degc[2] == pytest.approx(24.3, abs=1e-9)


def test_fault_code_from_a_module_is_a_failed_sensor(setup):
    config, emu, source = setup
    emu.set_temperatures({"spindle": float("nan")})        # broken element: fault code on the wire
    emu.set_word("rtd_b", "holding", 5, 0xFFFF)             # uint16 fault code
    source.poll_once()
    frame = TemperatureFrameBuilder(config).build(source.sample(1.0))
    assert list(frame.status) == [0, 3, 0, 3, 0]
    assert "sensor fault" in frame.reasons[1]


def test_server_restart_fails_all_then_the_poller_reconnects(setup):
    config, emu, source = setup
    builder = TemperatureFrameBuilder(config)
    source.start()
    assert wait_for(lambda: list(builder.build(source.sample(0.0)).status) == [0] * 5)
    connects = [link.connects for link in source.links]

    emu.stop()
    assert wait_for(lambda: list(builder.build(source.sample(1.0)).status) == [3] * 5)
    emu.set_temperatures({"ambient": 22.0})
    emu.start()
    assert wait_for(lambda: list(builder.build(source.sample(2.0)).status) == [0] * 5)
    assert builder.build(source.sample(3.0)).temperatures_degc[0] == pytest.approx(22.5, abs=1e-9)
    assert all(after > before for after, before in zip([l.connects for l in source.links], connects))


def test_unreachable_module_backs_off_exponentially(tmp_path, ports):
    path = tmp_path / "s.yaml"
    path.write_text(sensors_yaml(ports))
    config = load_sensor_config(path)
    now = [0.0]
    source = ModbusSource(config, clock=lambda: now[0])     # nothing listens on the ports
    link = next(l for l in source.links if "rtd_a" in l.modules)
    delays = []
    for _ in range(5):
        source.poll_once()
        delays.append(link.link_backoff.delay_s)
        now[0] = link.link_backoff.next_try                  # jump to the next allowed attempt
    assert delays == [0.05, 0.1, 0.2, 0.2, 0.2]              # doubled up to reconnect_max_s
    frame = TemperatureFrameBuilder(config).build(source.sample(1.0))
    assert list(frame.status) == [3] * 5
    assert "cannot connect" in frame.reasons[0]
    source.close()


def test_readings_older_than_max_age_are_failed_not_repeated(setup):
    config, emu, source = setup
    builder = TemperatureFrameBuilder(config)
    source.poll_once()
    assert builder.build(source.sample(10.0)).status[0] == SensorStatus.OK
    # no poll for a while (the sample reports the true age): max_age_s is 25 s
    t_read = source.store.acquired[0]
    source.clock = lambda: t_read + 30.0
    frame = builder.build(source.sample(40.0))
    assert list(frame.status) == [3] * 5 and "old" in frame.reasons[0]
