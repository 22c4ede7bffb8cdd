"""Candidate words for what a unit differs in beyond what the bounded calibration can say:

- ``beyond_tolerance``: a parameter that ended at its tolerance bound moves further (a link
  that conducts twice as well, a thermo-elastic term 50 % larger), reported as "beyond the
  builder's tolerance: X moved by Y", not as a new mechanism plus bounded parameters;
- ``follows``: a boundary holding a constant (a chiller's 22 degC) follows a temperature input
  instead (the hall), with a gain, an offset and a lag;
- ``extra_source``: a heat source the twin lacks on one of its bodies, driven by a machine input;
- ``sensor_drift``: the sensor an input is read from (the hall) is off by a bias and drifts.

Each word is a few parameters ``theta`` written into a machine description; ``theta0`` is where
its fit starts, ``release`` the calibration-section overrides that let the final calibration
move its parameters beyond the tolerances (or keep them fixed). No rclpy.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from thermal_twin.calibrate.bounds import Param
from thermal_twin.machine.schema import Machine

#: how far a parameter may go beyond its tolerance: within [v/F, v*F] of the type's value
BEYOND_FACTOR = 5.0
#: an added source may give at most this many watts at its input's maximum (negative: a sink)
SOURCE_RANGE_W = (-300.0, 800.0)
#: a following boundary's lag time constant, seconds
TAU_RANGE_S = (60.0, 48 * 3600.0)
#: a sensor's bias [K] and drift [K/h] in the drift word
BIAS_RANGE_K, DRIFT_RANGE_K_PER_H = 3.0, 0.05


@dataclass
class Word:
    kind: str
    label: str
    params: tuple[str, ...]
    theta0: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    apply: Callable[[dict, np.ndarray], None]           # writes theta into a description, in place
    describe: Callable[[np.ndarray], str]
    release: Callable[[np.ndarray], dict] = field(default=lambda theta: {})
    refuse: Callable[[np.ndarray], str] = field(default=lambda theta: "")   # why a fitted theta is no word


    def spec(self, base: Mapping, theta: np.ndarray) -> dict:
        out = copy.deepcopy(dict(base))
        self.apply(out, np.asarray(theta, float))
        return out


def _set(spec: dict, path: tuple, value: float) -> None:
    d = spec
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = float(value)


def beyond_tolerance(p: Param, value: float, type_value: float) -> Word:
    """Parameter ``p`` (at its bound, now ``value``) moving within BEYOND_FACTOR of the type's value."""
    v0 = type_value
    if v0 > 0 and p.kind != "gain":
        lo, hi = math.log(1.0 / BEYOND_FACTOR), math.log(BEYOND_FACTOR)
        to_v = lambda th: v0 * math.exp(th)           # noqa: E731 (one-line maps)
        start = math.log(max(value, 1e-12) / v0)
    else:
        half = (BEYOND_FACTOR - 1.0) * abs(v0) + 0.3
        lo, hi = -half, half
        to_v = lambda th: v0 + th                     # noqa: E731
        start = value - v0
    start = float(np.clip(start, lo, hi))

    def describe(th):
        v = to_v(th[0])
        change = f"{100.0 * (v / v0 - 1.0):+.0f} %" if v0 else f"{v - v0:+.3g} {p.unit}"
        return f"beyond the builder's tolerance: {p.name} moved by {change} ({v0:.4g} -> {v:.4g} {p.unit})"
    def refuse(th):
        v = to_v(th[0])
        return "within the builder's tolerance (the calibration's to say)" if p.lo <= v <= p.hi else ""
    return Word("beyond_tolerance", f"{p.name} beyond tolerance", (p.name,), np.array([start]), np.array([lo]),
                np.array([hi]), lambda s, th: _set(s, p.path, to_v(th[0])), describe,
                lambda th: {p.name: {"bounds": sorted([to_v(lo), to_v(hi)])}}, refuse)


def follows(machine: Machine, boundary: str, source: str, source_input: str, source_t0: float) -> Word:
    """Constant boundary ``boundary`` follows ``source`` (a boundary or input whose temperature is
    the input ``source_input``, first value ``source_t0``): theta = (gain, ln tau_s, offset shift);
    the offset keeps the boundary at its constant at the recording's start when the shift is 0."""
    c0 = float(machine.boundaries[boundary].temperature)

    def follow(th):
        g, tau, d = float(th[0]), math.exp(th[1]), float(th[2])
        return {"temperature": source, "gain": g, "offset": c0 + d - g * source_t0, "tau_s": tau}

    def apply(s, th):
        s["boundaries"][boundary] = {"follows": follow(th)}

    def describe(th):
        f = follow(th)
        return (f"added: boundary {boundary} follows {source} instead of holding {c0:g} degC: "
                f"T = {f['offset']:.2f} + {f['gain']:.2f} x {source} lagged by {f['tau_s'] / 3600.0:.2g} h")
    return Word("follows", f"{boundary} follows {source}", ("gain", "ln_tau_s", "offset_shift_K"),
                np.array([0.5, math.log(1800.0), 0.0]),
                np.array([0.0, math.log(TAU_RANGE_S[0]), -5.0]), np.array([1.5, math.log(TAU_RANGE_S[1]), 5.0]),
                apply, describe)


def extra_source(machine: Machine, node: str, inp: str) -> Word:
    """A heat source on ``node`` linear in input ``inp``; theta = watts at the input's maximum."""
    spec = machine.inputs[inp]
    top = spec.max if math.isfinite(spec.max) and spec.max > 0 else 1.0
    name = f"unit_{node}_{inp}"

    def apply(s, th):
        s["sources"][name] = {"node": node, "input": inp, "coefficient": float(th[0]) / top, "exponent": 1.0,
                              "note": "added by learn: a source the type's twin lacks"}

    def describe(th):
        return f"added: heat source on {node} driven by {inp}: {th[0]:.0f} W at {top:g} {spec.unit}".rstrip()
    return Word("extra_source", f"source on {node} driven by {inp}", ("watts_at_max",), np.array([0.0]),
                np.array([SOURCE_RANGE_W[0]]), np.array([SOURCE_RANGE_W[1]]), apply, describe,
                lambda th: {f"sources.{name}.coefficient": {"bounds": [SOURCE_RANGE_W[0] / top,
                                                                      SOURCE_RANGE_W[1] / top]}})


def sensor_drift(machine: Machine, sensor: str, bias0: float) -> Word:
    """The sensor an input is read from is off by a bias and drifts linearly (K/h)."""
    def apply(s, th):
        s["sensors"][sensor]["bias"] = float(th[0])
        s["sensors"][sensor]["drift_k_per_h"] = float(th[1])

    def describe(th):
        return (f"added: sensor {sensor} reads {th[0]:+.2f} K off and drifts {th[1]:+.4f} K/h "
                f"({24.0 * th[1]:+.2f} K/day); the twin and the soft sensors read it backwards")
    return Word("sensor_drift", f"{sensor} sensor bias and drift", ("bias_K", "drift_K_per_h"),
                np.array([float(np.clip(bias0, -BIAS_RANGE_K, BIAS_RANGE_K)), 0.0]),
                np.array([-BIAS_RANGE_K, -DRIFT_RANGE_K_PER_H]), np.array([BIAS_RANGE_K, DRIFT_RANGE_K_PER_H]),
                apply, describe, lambda th: {f"sensors.{sensor}.bias": "fixed"})


def candidates(machine: Machine, cal_spec: Mapping, at_bound: list[tuple[Param, float]],
               input_t0: Mapping[str, float]) -> list[Word]:
    """Every candidate word for ``machine`` (the type's twin) given the calibrated description
    ``cal_spec``, the parameters that ended at their bound (with their value) and the first value
    of every input in the recording."""
    at_bound = [(p, v) for p, v in at_bound if p.kind not in ("bias", "boundary")]
    type_values = {}
    for p, _ in at_bound:
        d = machine.spec
        for k in p.path:
            d = d[k]
        type_values[p.name] = float(d)
    from_sensor = {s.from_sensor for s in machine.inputs.values() if s.from_sensor}
    words = [beyond_tolerance(p, v, type_values[p.name]) for p, v in at_bound]
    temp_inputs = [n for n, s in machine.inputs.items() if s.unit == "degC"]
    holder = {b.temperature: name for name, b in machine.boundaries.items() if isinstance(b.temperature, str)}
    for b, spec in machine.boundaries.items():
        if isinstance(spec.temperature, (int, float)):
            words += [follows(machine, b, holder.get(i, i), i, input_t0[i]) for i in temp_inputs if i in input_t0]
    drivers = [n for n, s in machine.inputs.items() if s.kind == "machine" and s.unit != "degC"]
    words += [extra_source(machine, n, i) for n in machine.nodes for i in drivers]
    words += [sensor_drift(machine, s, float(cal_spec["sensors"][s].get("bias", 0.0))) for s in sorted(from_sensor)]
    return words
