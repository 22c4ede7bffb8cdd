"""Boundaries that follow another temperature (a chiller tracking the hall), lowered to inputs.

A following boundary ``b`` (``follows: {temperature: NAME, gain, offset, tau_s}``) has the
temperature ``offset + gain * y`` with ``y`` a first-order lag of NAME's temperature (an input,
or a boundary holding a constant or an input), the same lag as the sensors': ``y_k = a y_(k-1) +
(1 - a) T_k``, ``a = exp(-dt / tau_s)``, ``y_0 = T_0`` (the machine stood still long enough).
The thermal network knows only constant and input boundaries, so a machine with following
boundaries is *lowered*: each one becomes ``temperature: <b>_follows``, a declared environment
input whose values this module computes, in a batch (:func:`follow_series`) or online
(:class:`Followers`). Everything downstream (network, initial state, sensors) is unchanged.
"""
from __future__ import annotations

import copy
import math
from typing import Mapping

import numpy as np
from scipy.signal import lfilter

from thermal_twin.machine.schema import load_machine
from thermal_twin.machine.spec import FOLLOW_SUFFIX, Machine


def follow_input(boundary: str) -> str:
    """The input a following boundary is lowered to."""
    return f"{boundary}{FOLLOW_SUFFIX}"


def has_followers(machine: Machine) -> bool:
    return any(b.follows is not None for b in machine.boundaries.values())


def lower_spec(spec: Mapping) -> dict:
    """A copy of a machine description whose following boundaries read their lowered input."""
    out = copy.deepcopy(dict(spec))
    inputs = out.setdefault("inputs", {})
    for b, d in list(out.get("boundaries", {}).items()):
        if "follows" not in d:
            continue
        f = d["follows"]
        src = _source_default(out, f["temperature"])
        inputs[follow_input(b)] = {"kind": "environment", "unit": "degC", "min": -273.15,
                                   "default": float(f.get("offset", 0.0)) + float(f.get("gain", 1.0)) * src}
        out["boundaries"][b] = {"temperature": follow_input(b)}
    return out


def lowered(machine: Machine) -> Machine:
    """The machine with its following boundaries lowered to inputs (itself if it has none)."""
    if not has_followers(machine):
        return machine
    low = load_machine(lower_spec(machine.spec))
    low.source_path = machine.source_path
    return low


def _source_default(spec: Mapping, name: str) -> float:
    if name in spec.get("inputs", {}):
        return float(spec["inputs"][name].get("default", 0.0))
    t = spec["boundaries"][name]["temperature"]
    return _source_default(spec, t) if isinstance(t, str) else float(t)


def _resolve(machine: Machine, name: str) -> tuple[str | None, float]:
    """(input name or None, default or constant) of a followed temperature: an input, or a
    boundary holding an input or a constant."""
    while name not in machine.inputs and isinstance(machine.boundaries[name].temperature, str):
        name = machine.boundaries[name].temperature
    if name in machine.inputs:
        return name, float(machine.inputs[name].default)
    return None, float(machine.boundaries[name].temperature)


def follow_series(machine: Machine, time_s: np.ndarray, values: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The lowered inputs' values at every instant of ``time_s`` for the resolved input arrays
    ``values`` (every declared input present); empty when nothing follows."""
    t = np.asarray(time_s, float)
    out = {}
    for b, spec in machine.boundaries.items():
        f = spec.follows
        if f is None:
            continue
        name, const = _resolve(machine, f.temperature)
        src = np.asarray(values[name], float) if name is not None else np.full(t.size, const)
        out[follow_input(b)] = f.offset + f.gain * _lag(t, src, f.tau_s)
    return out


def _lag(t: np.ndarray, src: np.ndarray, tau_s: float) -> np.ndarray:
    if tau_s <= 0 or src.size < 2:
        return src.copy()
    a = np.exp(-np.diff(t) / tau_s)
    y = np.empty_like(src)
    y[0] = src[0]
    if np.ptp(a) <= 1e-12:
        y[1:] = lfilter([1.0 - a[0]], [1.0, -a[0]], src[1:], zi=[a[0] * src[0]])[0]
        return y
    for k in range(1, src.size):
        y[k] = a[k - 1] * y[k - 1] + (1.0 - a[k - 1]) * src[k]
    return y


class Followers:
    """The lowered inputs of a machine's following boundaries, advanced online: each
    :meth:`update` at a later instant lags from the value at the previous instant; several at
    one instant replace each other (the last inputs of an instant hold, as in simulate)."""

    def __init__(self, machine: Machine):
        self.specs = {b: s.follows for b, s in machine.boundaries.items() if s.follows is not None}
        self._sources = {b: _resolve(machine, f.temperature) for b, f in self.specs.items()}
        self.y: dict[str, float] = {}
        self._y_prev: dict[str, float] | None = None
        self._t: float | None = None
        self._dt = 0.0

    def update(self, t_s: float, inputs: Mapping[str, float]) -> None:
        if self._t is None or t_s > self._t:
            self._y_prev = dict(self.y) if self._t is not None else None
            self._dt = 0.0 if self._t is None else t_s - self._t
            self._t = float(t_s)
        for b, f in self.specs.items():
            name, const = self._sources[b]
            src = float(inputs.get(name, const)) if name is not None else const
            if self._y_prev is None or f.tau_s <= 0:
                self.y[b] = src
            else:
                a = math.exp(-self._dt / f.tau_s)
                self.y[b] = a * self._y_prev[b] + (1.0 - a) * src

    def values(self) -> dict[str, float]:
        """The lowered inputs now."""
        return {follow_input(b): f.offset + f.gain * self.y[b] for b, f in self.specs.items()}

    def to_state(self) -> dict:
        return {"t_s": self._t, "dt": self._dt, "y": dict(self.y), "y_prev": self._y_prev}

    def restore(self, state: Mapping) -> None:
        self._t = None if state.get("t_s") is None else float(state["t_s"])
        self._dt = float(state.get("dt", 0.0))
        self.y = {k: float(v) for k, v in (state.get("y") or {}).items()}
        yp = state.get("y_prev")
        self._y_prev = None if yp is None else {k: float(v) for k, v in yp.items()}
