"""`thermal-comp rtd-emulator`: help, errors naming the key, and serving a CSV over Modbus."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from thermal_sensors.modbus_source import ModbusSource
from thermal_sensors.rtd_emulator_cli import main
from thermal_sensors.sensor_config import load_sensor_config
from thermal_sensors.temperature_frame import TemperatureFrameBuilder

from sensor_test_data import make_recording, sensors_yaml, ports  # noqa: F401 (fixture)


def test_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    assert "--csv" in capsys.readouterr().out


def test_bad_config_names_the_key(tmp_path, capsys):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("sensors:\n  - {id: a, modbus: {module: m, address: -1}}\n"
                   "modbus: {modules: [{name: m}]}\n")
    make_recording(tmp_path / "r.csv", n_rows=3)
    assert main(["--config", str(cfg), "--csv", str(tmp_path / "r.csv")]) == 2
    assert "sensors[0].modbus.address: -1" in capsys.readouterr().err


def test_config_without_modbus_map_is_refused(tmp_path, capsys):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("sensors:\n  - {id: a}\n")
    make_recording(tmp_path / "r.csv", n_rows=3)
    assert main(["--config", str(cfg), "--csv", str(tmp_path / "r.csv")]) == 2
    assert "modbus.modules: missing" in capsys.readouterr().err


@pytest.mark.slow
def test_serves_a_recording_to_a_modbus_client_across_processes(tmp_path, ports):
    t, cols = make_recording(tmp_path / "r.csv", n_rows=8, dt_s=10.0)
    cfg = tmp_path / "s.yaml"
    cfg.write_text(sensors_yaml(ports))
    config = load_sensor_config(cfg)
    # 10 s rows at speed 50: a new row every 0.2 s; then hold the last one
    proc = subprocess.Popen([sys.executable, "-m", "thermal_sensors.rtd_emulator_cli", "--config", str(cfg),
                             "--csv", str(tmp_path / "r.csv"), "--speed", "50", "--hold"],
                            env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    source = ModbusSource(config)
    builder = TemperatureFrameBuilder(config)
    last = {s.id: cols[s.csv_column][-1] for s in config.sensors}
    try:
        deadline = time.monotonic() + 30
        frame = None
        while time.monotonic() < deadline and proc.poll() is None:
            source.poll_once()
            frame = builder.build(source.sample(0.0))
            if abs(frame.temperatures_degc[0] - (last["ambient"] + 0.5)) < 1e-9:
                break
            time.sleep(0.05)
        assert frame is not None and proc.poll() is None
        assert frame.temperatures_degc[4] == pytest.approx(last["cold"], abs=1e-9)   # negative int16
        assert frame.temperatures_degc[2] == pytest.approx(last["stuck"], abs=1e-9)  # uint16 + offset
        assert frame.temperatures_degc[0] == pytest.approx(last["ambient"] + 0.5, abs=1e-9)
    finally:
        source.close()
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, out
    assert "served 8 rows" in out


@pytest.mark.slow
@pytest.mark.ros
def test_serves_the_live_twin_readings(tmp_path, ports, ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray

    cfg = tmp_path / "s.yaml"
    cfg.write_text(sensors_yaml(ports))
    config = load_sensor_config(cfg)
    proc = subprocess.Popen([sys.executable, "-m", "thermal_sensors.rtd_emulator_cli", "--config", str(cfg),
                             "--twin"], env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    node = Node("fake_machine_sim", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    pub = node.create_publisher(TemperatureArray, "twin/sensor_readings", SENSOR_QOS)
    source = ModbusSource(config)
    builder = TemperatureFrameBuilder(config)
    ids = ["ambient", "spindle", "stuck", "hot", "cold"]

    def serve_and_read(values, status, expect_status):
        deadline = time.monotonic() + 30
        k = 0
        while time.monotonic() < deadline and proc.poll() is None:
            k += 1
            pub.publish(TemperatureArray(header=Header(stamp=s_to_stamp(float(k))), sensor_ids=ids,
                                         temperatures_degc=values, status=status))
            ex.spin_once(timeout_sec=0.05)
            source.poll_once()
            frame = builder.build(source.sample(float(k)))
            if list(frame.status) == expect_status:
                return frame
        return None
    try:
        deadline = time.monotonic() + 30
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline and proc.poll() is None:
            ex.spin_once(timeout_sec=0.05)
        frame = serve_and_read([21.3, 30.2, 24.3, 55.5, -7.9], [0] * 5, [0] * 5)
        assert frame is not None
        np.testing.assert_allclose(frame.temperatures_degc, [21.8, 1.01 * 30.2 - 0.2, 24.3, 55.5, -7.9],
                                   atol=1e-9)
        frame = serve_and_read([21.3, 30.2, 24.3, 55.5, -7.9], [0, 0, 0, 3, 0], [0, 0, 0, 3, 0])
        assert frame is not None and "sensor fault" in frame.reasons[3]
    finally:
        source.close()
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
        ex.shutdown()
        node.destroy_node()
    assert proc.returncode == 0, out
