"""A scenario played step by step, with probing pauses (the core of the machine_sim node).

Two clocks: simulated time ``t_s`` (what /clock shows) and the production programme's
clock (an index into the scenario's time line). ``step()`` runs the programme for one
time-line step. ``idle(duration)`` is a probing move: simulated time and the environment
(hall, coolant tank) go on, the programme clock stops and the machine's own inputs (speeds,
switches) take their idle defaults, so probing costs production time as on a real machine.
Environment inputs are looked up at simulated time (held at the last value after the end
of the time line); advancing is split at their change instants, so it stays exact.
"""
from __future__ import annotations


import numpy as np

from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.machine.schema import Machine
from thermal_twin.sim.simulate import TwinStepper, environment_input_names


class ScenarioRunner:
    def __init__(self, machine: Machine, timeline: InputsTimeline, seed: int = 0):
        self.machine = machine
        self.timeline = timeline
        self._vals = timeline.resolved(machine)
        self._t = timeline.time_s
        self._env = environment_input_names(machine)
        self.k = 0
        self.t_s = float(self._t[0])
        self.busy_probing = False
        self.stepper = TwinStepper(machine, self._inputs(programme=True), seed=seed)
        self.stepper.t_s = self.t_s

    # ----------------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        """The programme has reached the last instant of the time line."""
        return self.k >= len(self._t) - 1

    @property
    def programme_time_s(self) -> float:
        return float(self._t[self.k])

    def _env_index(self, t_s: float) -> int:
        return int(np.clip(np.searchsorted(self._t, t_s + 1e-9, side="right") - 1, 0, len(self._t) - 1))

    def _inputs(self, programme: bool) -> dict[str, float]:
        ke = self._env_index(self.t_s)
        out = {}
        for name, spec in self.machine.inputs.items():
            if name in self._env:
                out[name] = float(self._vals[name][ke])
            elif programme:
                out[name] = float(self._vals[name][self.k])
            else:
                out[name] = spec.default
        return out

    def inputs(self) -> dict[str, float]:
        """The inputs acting now."""
        return dict(self.stepper.inputs)

    def _advance(self, duration: float, programme: bool) -> None:
        remaining = float(duration)
        while remaining > 1e-12:
            self.stepper.set_inputs(self._inputs(programme))
            ke = self._env_index(self.t_s)
            next_change = float(self._t[ke + 1]) if ke + 1 < len(self._t) else np.inf
            seg = min(remaining, max(next_change - self.t_s, 1e-9))
            self.stepper.advance(seg)
            self.t_s += seg
            remaining -= seg
        self.stepper.t_s = self.t_s

    def step(self) -> None:
        """Run the programme over its next time-line step."""
        if self.done:
            raise RuntimeError("the scenario has ended")
        dt = float(self._t[self.k + 1] - self._t[self.k])
        self._advance(dt, programme=True)
        self.k += 1
        self.stepper.set_inputs(self._inputs(programme=True))

    def idle(self, duration_s: float) -> None:
        """Let ``duration_s`` seconds pass with the programme paused (a probing move)."""
        if not duration_s >= 0:
            raise ValueError(f"duration_s: {duration_s!r} must be >= 0")
        self._advance(duration_s, programme=False)
        self.stepper.set_inputs(self._inputs(programme=False))

    def resume(self) -> None:
        """Back to the programme's inputs after probing."""
        self.stepper.set_inputs(self._inputs(programme=True))

    def sensor_readings(self) -> dict[str, float]:
        return self.stepper.sensor_readings()

    def errors(self) -> dict[str, float]:
        return self.stepper.errors()
