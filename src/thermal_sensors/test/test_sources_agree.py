"""The three sources give the same calibrated, status-flagged stream for the same data."""
from __future__ import annotations

import numpy as np

from thermal_sensors.modbus_source import ModbusSource
from thermal_sensors.replay_source import ReplaySource
from thermal_sensors.rtd_emulator import RtdEmulator
from thermal_sensors.sensor_config import load_sensor_config
from thermal_sensors.sensor_status import SensorStatus
from thermal_sensors.temperature_frame import TemperatureFrameBuilder
from thermal_sensors.twin_source import TwinSource

from sensor_test_data import make_recording, sensors_yaml, ports  # noqa: F401 (fixture)


def test_twin_replay_and_modbus_streams_are_identical(tmp_path, ports):
    csv = tmp_path / "rec.csv"
    t, cols = make_recording(csv)
    cfg_path = tmp_path / "sensors.yaml"
    cfg_path.write_text(sensors_yaml(ports))
    config = load_sensor_config(cfg_path)

    replay = ReplaySource.from_csv(csv, config)
    b_replay = TemperatureFrameBuilder(config)
    replay_frames = [b_replay.build(replay.sample(tk)) for tk in t]

    twin = TwinSource(config)
    b_twin = TemperatureFrameBuilder(config)
    twin_ids = ["ambient", "spindle", "stuck", "hot", "cold"]   # the twin's sensor ids
    twin_frames = []
    for k, tk in enumerate(t):
        twin.accept(tk, twin_ids, [cols[f"{sid}_c"][k] for sid in twin_ids])
        twin_frames.append(b_twin.build(twin.sample(tk)))

    modbus = ModbusSource(config)
    b_modbus = TemperatureFrameBuilder(config)
    modbus_frames = []
    with RtdEmulator(config) as emu:
        for k, tk in enumerate(t):
            emu.set_temperatures({sid: cols[f"{config.sensors[i].csv_column}"][k]
                                  for i, sid in enumerate(config.sensor_ids)})
            modbus.poll_once()
            modbus_frames.append(b_modbus.build(modbus.sample(tk)))
    modbus.close()

    for k in range(len(t)):
        assert replay_frames[k].same_as(twin_frames[k]), (k, replay_frames[k], twin_frames[k])
        assert replay_frames[k].same_as(modbus_frames[k]), (k, replay_frames[k], modbus_frames[k])

    # and the stream carries every status, where the data says so
    status = np.array([f.status for f in replay_frames])
    ids = list(config.sensor_ids)
    spindle = status[:, ids.index("spindle")]
    assert set(np.flatnonzero(spindle == SensorStatus.FAILED)) == {5, 6, 17}
    stuck = status[:, ids.index("stuck")]
    assert np.all(stuck[t <= 55] == SensorStatus.OK) and np.all(stuck[t > 55] == SensorStatus.STALE)
    hot = status[:, ids.index("hot")]
    assert np.array_equal(hot == SensorStatus.OUT_OF_RANGE, 60.0 + 0.5 * t > 70.0)
    cold = np.array([f.temperatures_degc[ids.index("cold")] for f in replay_frames])
    assert cold.min() < 0 and np.all(status[:, ids.index("cold")] == SensorStatus.OK)
    # calibration applied: ambient = raw + 0.5
    amb = np.array([f.temperatures_degc[0] for f in modbus_frames])
    np.testing.assert_allclose(amb, cols["ambient_c"] + 0.5, atol=1e-9)
