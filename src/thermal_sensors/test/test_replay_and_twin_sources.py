"""Edge cases of the replay and twin sources."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_sensors.replay_source import ReplaySource
from thermal_sensors.sensor_config import SensorConfigError, parse_sensor_config
from thermal_sensors.sensor_status import SensorStatus
from thermal_sensors.temperature_frame import TemperatureFrameBuilder
from thermal_sensors.twin_source import TwinSource

from sensor_test_data import make_recording


def test_replay_holds_rows_with_their_age_and_fails_past_the_end(tmp_path):
    t, cols = make_recording(tmp_path / "r.csv", n_rows=5, dt_s=10.0)
    config = parse_sensor_config({"max_age_s": 15, "sensors": [{"id": "ambient"}]})
    src = ReplaySource.from_csv(tmp_path / "r.csv", config)
    b = TemperatureFrameBuilder(config)
    assert b.build(src.sample(-1.0)).status[0] == SensorStatus.FAILED          # before the data
    f = b.build(src.sample(14.0))                                              # row t=10, 4 s old
    assert f.status[0] == SensorStatus.OK and f.temperatures_degc[0] == cols["ambient_c"][1]
    assert b.build(src.sample(55.0)).status[0] == SensorStatus.OK              # last row, 15 s old
    f = b.build(src.sample(56.0))
    assert f.status[0] == SensorStatus.FAILED and "old" in f.reasons[0]


def test_replay_names_a_missing_column(tmp_path):
    make_recording(tmp_path / "r.csv", n_rows=3)
    config = parse_sensor_config({"sensors": [{"id": "x", "channel": "oil_tank"}]})
    with pytest.raises(SensorConfigError, match=r"sensors\[0\]\.channel: column 'oil_tank_c'"):
        ReplaySource.from_csv(tmp_path / "r.csv", config)


def test_replay_of_the_real_fl_thermal_recording_without_config(shared_dir):
    src = ReplaySource.from_csv(shared_dir / "data/fl_thermal/fl_thermal.csv")
    assert src.sensor_ids == tuple(f"t{i}_c" for i in range(1, 17))
    b = TemperatureFrameBuilder(src.config)
    frames = [b.build(src.sample(float(tk))) for tk in src.time_s[:200]]
    assert all((f.status == SensorStatus.OK).all() for f in frames)
    assert frames[0].temperatures_degc[4] == pytest.approx(31.4718556492793)   # t5_c, row 0


def test_twin_missing_or_failed_sensors_are_failed_and_extra_ones_ignored():
    config = parse_sensor_config({"sensors": [{"id": "amb", "channel": "ambient"},
                                              {"id": "noz", "channel": "mwf_nozzle"},
                                              {"id": "mot", "channel": "motor"}]})
    src = TwinSource(config)
    b = TemperatureFrameBuilder(config)
    assert (b.build(src.sample(0.0)).status == SensorStatus.FAILED).all()      # nothing received
    src.accept(10.0, ["ambient", "motor", "spindle_housing"], [20.1, 41.0, 30.0], [0, 3, 0])
    f = b.build(src.sample(10.0))
    assert list(f.status) == [SensorStatus.OK, SensorStatus.FAILED, SensorStatus.FAILED]
    assert "no sensor 'mwf_nozzle'" in f.reasons[1] and "'motor' failed" in f.reasons[2]
    assert f.temperatures_degc[0] == 20.1 and np.isnan(f.temperatures_degc[1:]).all()
    with pytest.raises(ValueError, match="2 ids, 1 values"):
        src.accept(11.0, ["a", "b"], [1.0])


def test_shipped_spindle_stand_config_raises_no_false_flag_on_the_real_recording(shared_dir):
    """46 h of real FL_THERMAL data: healthy sensors, so every sample must be OK."""
    from thermal_sensors.sensor_config import load_sensor_config, resolve_sensor_config
    config = load_sensor_config(resolve_sensor_config("spindle_stand"))
    src = ReplaySource.from_csv(shared_dir / "data/fl_thermal/fl_thermal.csv", config)
    b = TemperatureFrameBuilder(config)
    status = np.array([b.build(src.sample(float(tk))).status for tk in src.time_s])
    assert status.shape == (11115, 16) and (status == SensorStatus.OK).all()


def test_shipped_configs_resolve_by_name_and_unknown_names_list_them():
    from thermal_sensors.sensor_config import load_sensor_config, resolve_sensor_config, shipped_configs
    assert {"nmv5000", "swiss_lathe", "spindle_stand", "rtd_bench"} <= set(shipped_configs())
    for name in shipped_configs():
        assert load_sensor_config(resolve_sensor_config(name)).sensors
    assert load_sensor_config(resolve_sensor_config("swiss-lathe")).sensor_ids[0] == "ambient"
    with pytest.raises(SensorConfigError, match=r"'nmv9000'.*shipped: \["):
        resolve_sensor_config("nmv9000")


def test_time_master_instants_every_row_or_every_period(tmp_path):
    t, _ = make_recording(tmp_path / "r.csv", n_rows=7, dt_s=10.0)          # 0 .. 60 s
    src = ReplaySource.from_csv(tmp_path / "r.csv")
    np.testing.assert_array_equal(src.instants(), t)
    np.testing.assert_allclose(src.instants(15.0), [0, 15, 30, 45, 60])
    np.testing.assert_allclose(src.instants(25.0), [0, 25, 50])
    with pytest.raises(ValueError, match="period_s"):
        src.instants(-1.0)
