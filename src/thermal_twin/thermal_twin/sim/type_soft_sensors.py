"""Soft sensors from the machine type: the NOMINAL twin of the type, stepped online from the
inputs a model receives, gives virtual readings ``twin:<node>`` (node temperatures, degC) and
``twin:<error>`` (the type's predicted error components, deltas from the start).

A builder knows the twin (or an FE model) of the type before a machine is switched on; driven
by the same machine inputs as the unit (C speed, MWF flag and supply temperature, the hall
temperature from its sensor), it predicts the unit's error changes far better than the unit's
few temperatures do (docs/talc.md, "The machine type's physics as TALC's inputs"). On the twin the type model has the plant's
structure and differs only by the unit-to-unit tolerances; on a real machine the FE/twin
model's structural error adds to that.

Inputs map by the project's naming convention: a machine input comes from ``machine_state``
under its own name (a replayed recording) or its MachineState name
(``machine_state_fields.message_input_name``: ``C_axis_rpm``, ``coolant_temperature_degc``); an
input with ``from_sensor`` comes from that temperature sensor. The inputs of an instant hold
until the next one (zero-order hold, as :func:`thermal_twin.sim.simulate.simulate`); the twin
starts at its ``initial_state`` for the first instant's inputs. A missing or NaN input holds
its last value (its default before any), counted. A sensor the twin gives a bias, gain or
drift is read backwards through them (a unit twin's diagnosed hall-sensor bias and drift; the
drift at the instant's clock time). No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from thermal_comp_common.machine_state_fields import message_input_name

from thermal_twin.machine.schema import Machine, load_machine
from thermal_twin.physics.sensor_model import read_backwards
from thermal_twin.sim.simulate import TwinStepper

#: prefix of every soft-sensor name
PREFIX = "twin:"
STATE_VERSION = 1


class SoftSensorError(ValueError):
    """Bad input to the soft sensors; the message names the field and value."""


class TypeSoftSensors:
    """The nominal twin of ``machine`` stepped online (module docstring)."""

    def __init__(self, machine: Machine | str | Mapping):
        self.machine = machine if isinstance(machine, Machine) else load_machine(machine)
        self.input_names = list(self.machine.inputs)
        self._sources: dict[str, tuple[str, tuple[str, ...]]] = {}
        for name, spec in self.machine.inputs.items():
            if spec.from_sensor:
                self._sources[name] = ("temperatures", (spec.from_sensor,))
            else:
                self._sources[name] = ("machine_state", tuple(dict.fromkeys((name, message_input_name(name)))))
        self.stepper: TwinStepper | None = None
        self.t_s: float | None = None
        self.last_inputs: dict[str, float] = {}
        #: per twin input: instants at which it was missing or NaN (its last value held)
        self.held_counts: dict[str, int] = {n: 0 for n in self.input_names}
        #: the twin inputs held at the last instant
        self.held_now: list[str] = []
        self._names: list[str] | None = None
        self._gains: np.ndarray | None = None

    # ------------------------------------------------------------------ names and values
    @property
    def names(self) -> list[str]:
        """Every soft sensor: ``twin:<node>`` then ``twin:<error>``."""
        if self._names is None:
            probe = self.stepper or TwinStepper(self.machine, {})
            self._names = [PREFIX + n for n in probe.net.node_names] + [PREFIX + e for e in probe.error_map.names]
        return list(self._names)

    def values(self) -> dict[str, float]:
        """The soft sensors now (NaN before the first :meth:`update`)."""
        if self.stepper is None:
            return {n: math.nan for n in self.names}
        s = self.stepper
        e = s.error_map.errors(s.x, s.x_ref)
        return dict(zip(self.names, np.concatenate([s.x, np.atleast_1d(e)]).tolist()))

    def _inputs(self, temperatures: Mapping[str, float], machine_state: Mapping[str, float],
                t_s: float = 0.0) -> dict[str, float]:
        out, held = {}, []
        for name in self.input_names:
            where, keys = self._sources[name]
            signals = temperatures if where == "temperatures" else machine_state
            v = math.nan
            for key in keys:
                if key in signals:
                    try:
                        v = float(signals[key])
                    except (TypeError, ValueError):
                        raise SoftSensorError(f"soft sensors of {self.machine.name}: input '{name}' <- '{key}': "
                                              f"{signals[key]!r} is not a number") from None
                    break
            if where == "temperatures" and math.isfinite(v):
                v = self._true_temperature(keys[0], v, t_s)
            if math.isfinite(v):
                self.last_inputs[name] = v
            else:
                held.append(name)
                self.held_counts[name] += 1
                v = self.last_inputs.get(name, self.machine.inputs[name].default)
            out[name] = v
        self.held_now = held
        return out

    def _true_temperature(self, sensor: str, reading: float, t_s: float) -> float:
        """The temperature a reading of ``sensor`` at clock time ``t_s`` stands for: the twin's
        sensor model read backwards (reading = gain x T + bias + drift x t), so a unit twin's
        diagnosed bias and drift of the hall sensor reach the boundary it drives."""
        return float(read_backwards(self.machine.sensors.get(sensor), reading, t_s))

    def update(self, t_s: float, temperatures: Mapping[str, float],
               machine_state: Mapping[str, float]) -> dict[str, float]:
        """Advance the twin to ``t_s`` with the inputs of the last instant, then take this
        instant's inputs; returns the soft sensors at ``t_s``."""
        t_s = float(t_s)
        if not math.isfinite(t_s):
            raise SoftSensorError(f"soft sensors of {self.machine.name}: t_s {t_s!r} is not finite")
        if self.t_s is not None and t_s < self.t_s:
            raise SoftSensorError(f"soft sensors of {self.machine.name}: time {t_s} goes back (last {self.t_s})")
        u = self._inputs(temperatures, machine_state, t_s)
        if self.stepper is None:
            self.stepper = TwinStepper(self.machine, u)
        else:
            self.stepper.advance(t_s - self.t_s)
            self.stepper.set_inputs(u)
        self.t_s = t_s
        return self.values()

    # ------------------------------------------------------------------ persistence
    def to_state(self) -> dict[str, Any]:
        s = self.stepper
        return {"version": STATE_VERSION, "machine": self.machine.name, "t_s": self.t_s,
                "twin_t_s": s.t_s if s else None, "x": s.x.tolist() if s else None,
                "x_ref": s.x_ref.tolist() if s else None, "inputs": dict(s.inputs) if s else {},
                "followers": s.followers.to_state() if s else None,
                "last_inputs": dict(self.last_inputs), "held_counts": dict(self.held_counts)}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Resume from :meth:`to_state` (the machine type is this object's own)."""
        if state.get("version") != STATE_VERSION:
            raise SoftSensorError(f"soft-sensor state: 'version' {state.get('version')!r} is not {STATE_VERSION}")
        if state.get("machine") != self.machine.name:
            raise SoftSensorError(f"soft-sensor state: 'machine' {state.get('machine')!r} is not "
                                  f"{self.machine.name!r}")
        self.last_inputs = {k: float(v) for k, v in state["last_inputs"].items()}
        self.held_counts.update({k: int(v) for k, v in state["held_counts"].items()})
        self.t_s = None if state["t_s"] is None else float(state["t_s"])
        if state["x"] is None:
            self.stepper = None
            return
        s = TwinStepper(self.machine, state["inputs"])
        n = s.net.n
        for key in ("x", "x_ref"):
            if len(state[key]) != n:
                raise SoftSensorError(f"soft-sensor state: '{key}' has {len(state[key])} values, the twin of "
                                      f"{self.machine.name} has {n} nodes")
        s.x, s.x_ref = np.asarray(state["x"], float), np.asarray(state["x_ref"], float)
        s.t_s = float(state["twin_t_s"])
        if state.get("followers") is not None:       # states of twins without following boundaries lack it
            s.followers.restore(state["followers"])
        self.stepper = s
