"""Piecewise-constant input time lines that drive the twin.

``values[name][k]`` holds from ``time_s[k]`` to ``time_s[k+1]``; outputs of a simulation
are sampled at every ``time_s[k]``. Inputs a machine declares but the time line lacks take
the machine's default; names the machine does not know are an error.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thermal_twin.machine.schema import Machine
from thermal_twin.physics.sensor_model import read_backwards
from thermal_comp_common.machine_state_fields import message_input_name
from thermal_comp_common.recording_csv import Recording


class TimelineError(ValueError):
    """An input time line does not fit the machine; the message names the input and value."""


@dataclass
class InputsTimeline:
    time_s: np.ndarray
    values: dict[str, np.ndarray]
    name: str = ""
    events: list[tuple[float, str]] = field(default_factory=list)   # (t_s, description), informative

    def __post_init__(self):
        self.time_s = np.asarray(self.time_s, dtype=float)
        if self.time_s.ndim != 1 or len(self.time_s) < 1:
            raise TimelineError(f"time_s: need a 1-D array with at least one instant, got shape {self.time_s.shape}")
        if np.any(np.diff(self.time_s) <= 0):
            k = int(np.flatnonzero(np.diff(self.time_s) <= 0)[0]) + 1
            raise TimelineError(f"time_s[{k}]: {float(self.time_s[k])!r} does not increase "
                                f"(previous {float(self.time_s[k - 1])!r})")
        for k, v in list(self.values.items()):
            a = np.asarray(v, dtype=float)
            if a.shape != self.time_s.shape:
                raise TimelineError(f"input '{k}': {a.shape} values, time_s has {self.time_s.shape}")
            if not np.all(np.isfinite(a)):
                j = int(np.flatnonzero(~np.isfinite(a))[0])
                raise TimelineError(f"input '{k}': value {float(a[j])!r} at t={float(self.time_s[j])} s is not finite")
            self.values[k] = a

    def __len__(self) -> int:
        return len(self.time_s)

    def resolved(self, machine: Machine) -> dict[str, np.ndarray]:
        """Every machine input as an array (defaults filled), checked against the declared range."""
        unknown = [k for k in self.values if k not in machine.inputs]
        if unknown:
            raise TimelineError(f"input '{unknown[0]}' is not declared by machine '{machine.name}' "
                                f"(its inputs: {', '.join(machine.inputs)})")
        out = {}
        for name, spec in machine.inputs.items():
            a = self.values.get(name)
            if a is None:
                a = np.full(len(self.time_s), spec.default)
            bad = (a < spec.min) | (a > spec.max)
            if np.any(bad):
                j = int(np.flatnonzero(bad)[0])
                raise TimelineError(f"input '{name}': {float(a[j])!r} at t={float(self.time_s[j])} s is outside "
                                    f"[{spec.min}, {spec.max}] {spec.unit}")
            out[name] = a
        return out

    @classmethod
    def constant(cls, duration_s: float, step_s: float, **inputs: float) -> "InputsTimeline":
        t = np.arange(0.0, duration_s + 0.5 * step_s, step_s)
        return cls(t, {k: np.full(len(t), float(v)) for k, v in inputs.items()})


def timeline_from_recording(machine: Machine, rec: Recording) -> InputsTimeline:
    """The inputs of a recording as a time line for ``machine``.

    Input columns the machine declares are taken as they are, under the twin's name or the
    name a cell's bag gives it (MachineState: ``C_axis_rpm`` for ``c_speed_rpm``,
    ``machine_state_fields.message_input_name``); a missing input with ``from_sensor`` is filled
    from that sensor's column (real recordings have no true ambient, only an ambient sensor),
    read backwards through the twin's sensor model (its bias, gain and drift:
    ``sensor_model.read_backwards``); others take their default. Unknown input columns of the recording are ignored.
    """
    vals: dict[str, np.ndarray] = {}
    for name, spec in machine.inputs.items():
        if name in rec.columns:
            vals[name] = rec.columns[name]
        elif message_input_name(name) in rec.columns:
            vals[name] = rec.columns[message_input_name(name)]
        elif spec.from_sensor and f"{spec.from_sensor}_c" in rec.columns:
            col = np.asarray(rec.columns[f"{spec.from_sensor}_c"], dtype=float)
            if np.any(~np.isfinite(col)):
                good = np.isfinite(col)
                if not np.any(good):
                    raise TimelineError(f"input '{name}': sensor column '{spec.from_sensor}_c' has no valid value")
                col = np.interp(rec.time_s, rec.time_s[good], col[good])
            vals[name] = read_backwards(machine.sensors.get(spec.from_sensor), col, rec.time_s)
    return InputsTimeline(rec.time_s, vals, name=rec.source)
