"""Data for the sensor tests: free loopback ports, a small test recording and its sensor YAML.

(No conftest.py in this folder: a second module named conftest would shadow
test/conftest.py for tests that import it.)
"""
from __future__ import annotations

import socket

import numpy as np
import pytest

from thermal_comp_common.recording_csv import write_recording_csv


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def ports():
    """Three distinct free loopback ports (import this fixture into a test module)."""
    got: list[int] = []
    while len(got) < 3:
        p = free_port()
        if p not in got:
            got.append(p)
    return got


def make_recording(path, n_rows: int = 40, dt_s: float = 10.0, seed: int = 7):
    """A recording CSV with 0.1 degC resolution (what int16 tenths can carry exactly):

    ``ambient`` drifts, ``spindle`` warms up and sometimes reads NaN (failed), ``stuck``
    holds one value (stale), ``hot`` leaves its range, ``cold`` is below 0 degC
    (negative int16 registers). Returns (time_s, {column: values}).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_rows) * dt_s
    cols = {
        "spindle_rpm": np.where(t > 50, 3000.0, 0.0),
        "ambient_c": np.round(20.0 + 0.01 * t + rng.normal(0, 0.2, n_rows), 1),
        "spindle_c": np.round(22.0 + 8.0 * (1 - np.exp(-t / 150.0)) + rng.normal(0, 0.1, n_rows), 1),
        "stuck_c": np.full(n_rows, 24.3),
        "hot_c": np.round(60.0 + 0.5 * t, 1),
        "cold_c": np.round(-12.5 + 0.05 * t, 1),
        "E_X0C": np.zeros(n_rows),
    }
    cols["spindle_c"][[k for k in (5, 6, 17) if k < n_rows]] = np.nan
    write_recording_csv(path, t, cols)
    return t, cols


def sensors_yaml(ports: list[int]) -> str:
    """Sensor YAML for the test recording: two Modbus TCP modules on one port (unit 1, 2)
    and one RTU module (RTU frames over a socket), int16 and uint16 registers."""
    return f"""
max_age_s: 25.0
sensors:
  - id: ambient
    range_degc: [0, 40]
    stale_after_s: 200
    calibration: {{offset_degc: 0.5, gain: 1.0}}
    modbus: {{module: rtd_a, address: 0, type: int16, scale: 0.1}}
  - id: spindle
    range_degc: [0, 60]
    stale_after_s: 200
    calibration: {{offset_degc: -0.2, gain: 1.01}}
    modbus: {{module: rtd_a, address: 1, type: int16, scale: 0.1}}
  - id: stuck
    range_degc: [0, 60]
    stale_after_s: 55
    modbus: {{module: rtd_b, address: 4, register: holding, type: uint16, scale: 0.01, offset_degc: -50.0}}
  - id: hot
    range_degc: [0, 70]
    modbus: {{module: rtd_b, address: 5, register: holding, type: uint16, scale: 0.1}}
  - id: cold
    channel: cold
    range_degc: [-30, 40]
    modbus: {{module: rtd_c, address: 2, type: int16, scale: 0.1}}
modbus:
  modules:
    - {{name: rtd_a, transport: tcp, host: 127.0.0.1, port: {ports[0]}, unit_id: 1,
       timeout_s: 0.3, reconnect_min_s: 0.05, reconnect_max_s: 0.2, poll_period_s: 0.05}}
    - {{name: rtd_b, transport: tcp, host: 127.0.0.1, port: {ports[0]}, unit_id: 2,
       timeout_s: 0.3, reconnect_min_s: 0.05, reconnect_max_s: 0.2, poll_period_s: 0.05}}
    - {{name: rtd_c, transport: rtu, serial_port: "socket://127.0.0.1:{ports[1]}", unit_id: 7,
       timeout_s: 0.3, reconnect_min_s: 0.05, reconnect_max_s: 0.2, poll_period_s: 0.05}}
"""
