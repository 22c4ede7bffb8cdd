"""A twin started from what its sensors read at t = 0, for a recording that starts warm.

The idle steady state is right for a machine that stood still long enough; a recording that
starts mid-day (or a segment of a longer one) starts warm, and the twin started cold carries a
decaying offset the calibration then mistakes for physics. With ``initial_state: {readings:
{SENSOR: degC}}`` the nodes the sensors see take the readings (through each sensor's gain,
bias and weights), and every other node is at the equilibrium of its own heat balance with its
neighbours and the boundaries under the inputs of t = 0 (the quasi-steady state of a hidden
node between measured ones). Solved as one least-squares system: the sensor equations, and the
steady-state rows of the nodes no sensor pins (a sensor pins the node it weighs most). No rclpy.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from thermal_twin.machine.schema import load_machine
from thermal_twin.physics.thermal_network import ThermalNetwork


def readings_state(net: ThermalNetwork, inputs: Mapping[str, float], readings: Mapping[str, float]) -> np.ndarray:
    """Node temperatures consistent with ``readings`` (sensor id -> degC at t = 0) and, for the
    nodes no sensor pins, with their steady heat balance under ``inputs``."""
    machine = net.machine
    K, Kb = net.matrices(inputs)
    tb = net.boundary_temperatures(inputs)
    rhs = Kb @ tb + net.source_powers(inputs, 0.0)
    node_index = {n: i for i, n in enumerate(net.node_names)}
    b_index = {b: i for i, b in enumerate(net.boundary_names)}
    rows, values, pinned = [], [], set()
    for sid, reading in readings.items():
        s = machine.sensors[sid]
        w = np.zeros(net.n)
        seen_b = 0.0
        for place, weight in s.weights:
            if place in node_index:
                w[node_index[place]] += weight
            else:
                seen_b += weight * tb[b_index[place]]
        if not np.any(w) or not np.isfinite(reading):
            continue                   # a sensor of the hall or an empty reading says nothing of the nodes
        rows.append(s.gain * w)
        values.append(float(reading) - s.bias - s.gain * seen_b)
        pinned.add(int(np.argmax(np.abs(w))))
    free = [i for i in range(net.n) if i not in pinned]
    scale = np.abs(K).max() or 1.0    # the heat-balance rows (W/K) brought to the sensors' (K) size
    A = np.vstack([np.array(rows).reshape(-1, net.n), K[free] / scale])
    b = np.concatenate([np.array(values, dtype=float), rhs[free] / scale])
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    return x


#: how a recording may start the twin: its idle equilibrium, or where its first readings put it
START_MODES = ("steady", "readings")


def start_state(spec: Mapping, rec, mode: str) -> str | dict:
    """The ``initial_state`` a run of ``rec`` starts ``spec``'s twin in, by ``mode`` (:data:`START_MODES`)."""
    if mode not in START_MODES:
        raise ValueError(f"initial state: {mode!r} is not one of {', '.join(START_MODES)}")
    if mode == "steady":
        return "steady"
    machine = load_machine(spec)
    readings = first_readings(machine, rec.columns)
    if not readings:
        raise ValueError(f"initial state 'readings': recording {rec.source or '?'} has no reading of a sensor of "
                         f"twin '{machine.name}' ({', '.join(s.column for s in machine.sensors.values())}) "
                         "in its first rows")
    return {"readings": readings}


def first_readings(machine, columns: Mapping[str, np.ndarray], rows: int = 5) -> dict[str, float]:
    """Each sensor's reading at the start of a recording: the median of its first ``rows`` finite
    values among the first 2 * ``rows`` rows (one noisy sample would set a node's whole history)."""
    out: dict[str, float] = {}
    for sid, s in machine.sensors.items():
        col = columns.get(s.column)
        if col is None:
            continue
        head = np.asarray(col[:2 * rows], dtype=float)
        head = head[np.isfinite(head)][:rows]
        if head.size:
            out[sid] = float(np.median(head))
    return out


def own_reference(machine, rec):
    """The recording with every displacement channel relative to its first finite value: a twin
    started where the recording starts has its displacements start at 0, so the recording's must
    too (a run cut from a longer recording starts wherever the machine had drifted to)."""
    out = rec.slice(0, len(rec))
    for c in machine.errors:
        if c in out.columns:
            v = np.asarray(out.columns[c], dtype=float)
            ok = np.flatnonzero(np.isfinite(v))
            if ok.size:
                out.columns[c] = v - v[ok[0]]
    return out
