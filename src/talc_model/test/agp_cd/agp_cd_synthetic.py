"""Synthetic lathe-like recordings with known structure for the AGP / virtual-experiment tests.

A lumped first-order network (driven-tool motor fast, spindle motor slower, tool holder, cutting
oil with an optional set-point step, ambient day cycle) and errors that are static linear maps
of the temperatures (so a static GP on the temperatures can represent them exactly):
``GB_X`` (guide-bush TLS) and ``T02_X`` (a second tool position, offset by a holder gradient).
"""
from __future__ import annotations

import numpy as np

from thermal_comp_common.recording_csv import Recording


def lag(u: np.ndarray, dt: float, tau: float, y0: float) -> np.ndarray:
    y = np.empty_like(u)
    a = np.exp(-dt / tau)
    prev = y0
    for k, v in enumerate(u):
        prev = a * prev + (1 - a) * v
        y[k] = prev
    return y


def lathe_recording(hours: float = 30.0, dt: float = 120.0, seed: int = 0, oil_step_h: float | None = 18.0,
                    oil_step_c: float = 8.0, hold_h: tuple[float, float] = (1.0, 3.0)) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0 + dt / 2, dt)
    n = t.size
    rpm = np.zeros(n)
    k = 0
    while k < n:
        length = int(rng.uniform(*hold_h) * 3600.0 / dt)
        rpm[k:k + length] = rng.choice([0.0, 1500.0, 3000.0, 4500.0, 6000.0])
        k += length
    ambient = 21.0 + 1.5 * np.sin(2 * np.pi * t / 86400.0)
    oil_set = np.full(n, 24.0)
    if oil_step_h is not None:
        oil_set[t >= oil_step_h * 3600.0] += oil_step_c
    oil = lag(oil_set, dt, 1800.0, 24.0)
    tool = lag(ambient + 20.0 * (rpm / 6000.0) ** 1.5, dt, 600.0, 21.0)
    spindle = lag(ambient + 12.0 * rpm / 6000.0, dt, 2400.0, 21.0)
    holder = lag(0.6 * tool + 0.2 * oil + 0.2 * ambient, dt, 1200.0, 21.0 * 0.8 + 4.8)
    noise = lambda: rng.normal(0.0, 0.02, n)
    temps = {"tool_c": tool + noise(), "spindle_c": spindle + noise(), "oil_c": oil + noise(),
             "ambient_c": ambient + noise(), "holder_c": holder + noise()}
    d = {k: v - v[0] for k, v in {"tool": tool, "spindle": spindle, "oil": oil, "holder": holder}.items()}
    gb = 1.2 * d["holder"] + 0.8 * d["spindle"] + 1.0 * d["oil"]
    t02 = gb + 0.5 * (d["tool"] - d["holder"])
    cols = {**temps, "spindle_rpm": rpm, "GB_X_um": gb, "T02_X_um": t02}
    return Recording(t, {k: np.asarray(v, dtype=float) for k, v in cols.items()}, source="synthetic-lathe")
