"""Benchmark ``thermal-comp bench sensors``: Modbus poll latency against the RTD emulator
on loopback (TCP and RTU frames, a silent module), and frame building throughput.

Figures (all measured here, nothing asserted):
``modbus_tcp.poll_ms_p50/p99`` one poll of two modules (6 + 2 registers) over Modbus TCP;
``modbus_rtu.poll_ms_p50/p99`` one poll of one module over RTU frames on a socket;
``silent_module.poll_ms_p50/max`` an RTU poll whose module does not answer (timeout 0.2 s);
``frames.per_s`` calibrated, status-flagged frames per second for the 16 FL_THERMAL sensors.
"""
from __future__ import annotations

import socket
import pathlib
import time

import numpy as np

from thermal_sensors.modbus_source import ModbusSource
from thermal_sensors.rtd_emulator import RtdEmulator
from thermal_sensors.sensor_config import load_sensor_config, parse_sensor_config, resolve_sensor_config
from thermal_sensors.temperature_frame import TemperatureFrameBuilder
from thermal_sensors.temperature_source import RawSample


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _config(timeout_s: float = 0.2):
    tcp, rtu = _free_port(), _free_port()
    common = {"timeout_s": timeout_s, "reconnect_min_s": 0.001, "reconnect_max_s": 0.001}
    sensors = [{"id": f"a{i}", "modbus": {"module": "tcp1", "address": i}} for i in range(6)]
    sensors += [{"id": f"b{i}", "modbus": {"module": "tcp2", "address": 10 + i, "register": "holding",
                                           "type": "uint16", "scale": 0.01, "offset_degc": -273.15}}
                for i in range(2)]
    sensors += [{"id": f"r{i}", "modbus": {"module": "rtu", "address": i}} for i in range(6)]
    return parse_sensor_config({"sensors": sensors, "modbus": {"modules": [
        {"name": "tcp1", "port": tcp, "unit_id": 1, **common},
        {"name": "tcp2", "port": tcp, "unit_id": 2, **common},
        {"name": "rtu", "transport": "rtu", "serial_port": f"socket://127.0.0.1:{rtu}", "unit_id": 3,
         **common}]}})


def _time_polls(link, n: int, pause_s: float = 0.0) -> np.ndarray:
    out = np.empty(n)
    for k in range(n):
        time.sleep(pause_s)  # past the back-off (1 ms here), so every poll really tries
        t0 = time.perf_counter()
        link.poll_once()
        out[k] = (time.perf_counter() - t0) * 1e3
    return out


def run(args) -> dict:
    n = 50 if getattr(args, "quick", False) else 300
    config = _config()
    emu = RtdEmulator(config)
    emu.start()
    emu.set_temperatures({sid: 20.0 + i for i, sid in enumerate(config.sensor_ids)})
    source = ModbusSource(config)
    try:
        tcp_link = next(l for l in source.links if "tcp1" in l.modules)
        rtu_link = next(l for l in source.links if "rtu" in l.modules)
        _time_polls(tcp_link, 5)
        _time_polls(rtu_link, 5)
        tcp = _time_polls(tcp_link, n)
        rtu = _time_polls(rtu_link, n)
        emu.set_silent("rtu")
        silent = _time_polls(rtu_link, 10, pause_s=0.005)
    finally:
        source.close()
        emu.stop()

    cfg16 = load_sensor_config(resolve_sensor_config("spindle_stand"))
    builder = TemperatureFrameBuilder(cfg16)
    rng = np.random.default_rng(0)
    m = 2000 if getattr(args, "quick", False) else 20000
    samples = [RawSample(float(k), 25 + rng.normal(0, 0.1, 16), np.ones(16, bool), np.full(16, float(k)),
                         [""] * 16) for k in range(m)]
    t0 = time.perf_counter()
    for s in samples:
        builder.build(s)
    per_s = m / (time.perf_counter() - t0)

    figures = {
        "modbus_tcp": {"poll_ms_p50": float(np.percentile(tcp, 50)), "poll_ms_p99": float(np.percentile(tcp, 99)),
                       "polls": n, "modules": 2, "registers": 8},
        "modbus_rtu": {"poll_ms_p50": float(np.percentile(rtu, 50)), "poll_ms_p99": float(np.percentile(rtu, 99)),
                       "polls": n, "modules": 1, "registers": 6},
        "silent_module": {"timeout_s": 0.2, "poll_ms_p50": float(np.percentile(silent, 50)),
                          "poll_ms_max": float(silent.max())},
        "frames": {"per_s": float(per_s), "sensors": 16},
    }
    out_dir = getattr(args, "out_dir", None)
    if out_dir:
        figures["plot"] = _plot(out_dir, tcp, rtu, silent)
    for group, vals in figures.items():
        if not isinstance(vals, dict):
            print(group, vals)
            continue
        print(group, ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in vals.items()))
    return figures


def _plot(out_dir: str, tcp: np.ndarray, rtu: np.ndarray, silent: np.ndarray) -> str:
    """Histogram of the poll latencies (log axis): the PNG path."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    fig, ax = plt.subplots(figsize=(7, 3.5))
    bins = np.logspace(np.log10(min(tcp.min(), rtu.min()) * 0.8), np.log10(silent.max() * 1.2), 60)
    ax.hist(tcp, bins=bins, alpha=0.7, label=f"TCP, 2 modules (p50 {np.median(tcp):.2g} ms)")
    ax.hist(rtu, bins=bins, alpha=0.7, label=f"RTU frames, 1 module (p50 {np.median(rtu):.2g} ms)")
    ax.hist(silent, bins=bins, alpha=0.7, label="silent module, timeout 200 ms")
    ax.set_xscale("log")
    ax.set_xlabel("poll duration, ms (loopback, emulator)")
    ax.set_ylabel("polls")
    ax.legend(fontsize=8)
    ax.set_title("Modbus poll latency")
    fig.tight_layout()
    path = pathlib.Path(out_dir) / "sensors_modbus_poll_latency.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)
