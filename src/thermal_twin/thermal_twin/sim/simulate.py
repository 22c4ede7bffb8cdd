"""Run the twin: :func:`simulate` for a whole time line, :class:`TwinStepper` step by step.

Both share one core: the exact network step (:mod:`thermal_network`), the sensor bank
(:mod:`sensor_model`) and the error map (:mod:`thermo_elastic`). Randomness (sensor noise)
comes from ``numpy.random.default_rng(seed)``; the same seed gives identical output.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from thermal_twin.sim.initial_state import readings_state
from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.machine.schema import Machine, load_machine
from thermal_comp_common.recording_csv import Recording
from thermal_twin.physics.boundary_follow import Followers, follow_series, lowered
from thermal_twin.physics.sensor_model import SensorBank
from thermal_twin.physics.thermal_network import ThermalNetwork
from thermal_twin.physics.thermo_elastic import ErrorMap


def _as_machine(machine: Machine | str | Mapping) -> Machine:
    return machine if isinstance(machine, Machine) else load_machine(machine)


def environment_input_names(machine: Machine) -> set[str]:
    """Inputs that go on while the machine stands still: environment inputs and the
    temperatures of boundaries (hall, coolant tank, oil)."""
    keep = {n for n, s in machine.inputs.items() if s.kind == "environment"}
    keep |= {b.temperature for b in machine.boundaries.values() if isinstance(b.temperature, str)}
    keep |= {b.follows.temperature for b in machine.boundaries.values() if b.follows is not None}
    return keep


def idle_inputs(machine: Machine, inputs: Mapping[str, float]) -> dict[str, float]:
    """The inputs of an idle machine in its environment at this instant: environment inputs
    and boundary temperatures (coolant supply, oil) as given, every other machine input
    (speeds, powers, switches) at its default."""
    keep = environment_input_names(machine)
    return {n: (float(inputs[n]) if n in keep and n in inputs else s.default)
            for n, s in machine.inputs.items()}


def initial_temperatures(net: ThermalNetwork, inputs: Mapping[str, float]) -> np.ndarray:
    """Node temperatures at t = 0 as the machine's ``initial_state`` says: ``steady`` is
    the equilibrium of the idle machine with its environment at t = 0 (:func:`idle_inputs`),
    i.e. a machine that has stood still long enough, as at the start of a test; ``readings``
    the state the sensors read at t = 0 (:func:`~thermal_twin.sim.initial_state.readings_state`)."""
    init = net.machine.initial_state
    if init == "steady":
        return net.steady_state(idle_inputs(net.machine, inputs), 0.0)
    if "readings" in init:          # a recording that starts warm (sim/initial_state.py)
        return readings_state(net, inputs, init["readings"])
    tb = net.boundary_temperatures(inputs)
    return np.full(net.n, tb[net.boundary_names.index(init["boundary"])])


class TwinStepper:
    """The twin advanced in increments (used by the machine_sim node).

    ``set_inputs(u)`` sets the inputs that hold from now on (they also set the boundary
    temperatures seen now), ``advance(dt)`` integrates ``dt`` seconds with them (exact);
    ``sensor_readings()`` and ``errors()`` describe the current instant. Sampling
    set_inputs(u_k) then reading at every t_k reproduces :func:`simulate`. Following boundaries
    run on the lowered machine, their inputs advanced by :class:`Followers`.
    """

    def __init__(self, machine: Machine | str | Mapping, initial_inputs: Mapping[str, float],
                 seed: int = 0):
        self.machine = _as_machine(machine)
        self.followers = Followers(self.machine)
        self.net = ThermalNetwork(lowered(self.machine))
        self.sensors = SensorBank(self.machine, self.net.node_names, self.net.boundary_names)
        self.error_map = ErrorMap(self.machine, self.net.node_names)
        self.rng = np.random.default_rng(seed)
        self.inputs = dict(initial_inputs)
        self.t_s = 0.0
        self.followers.update(self.t_s, self.inputs)
        self.x = initial_temperatures(self.net, self.net_inputs())
        self.x_ref = self.x.copy()
        self._last_read_t: float | None = None

    def set_inputs(self, inputs: Mapping[str, float]) -> None:
        unknown = [k for k in inputs if k not in self.machine.inputs]
        if unknown:
            raise ValueError(f"input '{unknown[0]}' is not declared by machine '{self.machine.name}'")
        self.inputs = {**self.inputs, **{k: float(v) for k, v in inputs.items()}}
        self.followers.update(self.t_s, self.inputs)

    def net_inputs(self) -> dict[str, float]:
        """The inputs with the following boundaries' lowered inputs."""
        return {**self.inputs, **self.followers.values()} if self.followers.specs else self.inputs

    def advance(self, dt: float) -> None:
        """Integrate ``dt`` seconds with the current inputs held constant (exact)."""
        if not dt >= 0:
            raise ValueError(f"dt: {dt!r} must be >= 0")
        if dt > 0:
            self.x = self.net.step(self.x, self.net_inputs(), self.t_s, dt)
            self.t_s += dt

    def boundary_temperatures(self) -> np.ndarray:
        return self.net.boundary_temperatures(self.net_inputs())

    def sensor_readings(self) -> dict[str, float]:
        """Readings now. Each call is one sample: it advances the sensors' lag filters and
        draws noise, so call it once per published instant (as :func:`simulate` does)."""
        dt = 0.0 if self._last_read_t is None else self.t_s - self._last_read_t
        self._last_read_t = self.t_s
        r = self.sensors.read(self.x, self.boundary_temperatures(), dt, self.rng, self.t_s)
        return dict(zip(self.sensors.ids, r.tolist()))

    def errors(self) -> dict[str, float]:
        return dict(zip(self.error_map.names, self.error_map.errors(self.x, self.x_ref).tolist()))

    def node_temperatures(self) -> dict[str, float]:
        return dict(zip(self.net.node_names, self.x.tolist()))


@dataclass
class SimulationResult:
    """Outputs sampled at every instant of the time line."""

    machine: Machine
    time_s: np.ndarray
    inputs: dict[str, np.ndarray]              # as applied from time_s[k]
    sensors: dict[str, np.ndarray]            # readings by sensor id, degC
    errors: dict[str, np.ndarray]             # true error components (um or um/m)
    node_temperatures: np.ndarray             # (len(time_s), n_nodes), degC
    boundary_temperatures: np.ndarray         # (len(time_s), n_boundaries), degC
    name: str = ""
    events: list = field(default_factory=list)

    def columns(self) -> dict[str, np.ndarray]:
        """Recording-CSV columns: inputs, then ``<sensor>_c``, then the error components."""
        cols: dict[str, np.ndarray] = {}
        for k in self.machine.inputs:
            cols[k] = self.inputs[k]
        for sid, v in self.sensors.items():
            cols[self.machine.sensors[sid].column] = v
        cols.update(self.errors)
        return cols

    def to_recording(self) -> Recording:
        return Recording(self.time_s.copy(), {k: np.asarray(v).copy() for k, v in self.columns().items()},
                         source=f"twin:{self.machine.name}:{self.name}")


def simulate(machine: Machine | str | Mapping, timeline: InputsTimeline, seed: int = 0,
             progress: Callable[[int], None] | None = None) -> SimulationResult:
    """Simulate ``machine`` over ``timeline`` (exact for its piecewise-constant inputs).

    ``progress(n)`` is called with the number of steps done since the last call (tqdm's
    ``update``), every 1000 steps and at the end.
    """
    m = _as_machine(machine)
    vals = timeline.resolved(m)
    t = timeline.time_s
    n_t = len(t)
    net = ThermalNetwork(lowered(m))
    sensors = SensorBank(m, net.node_names, net.boundary_names)
    emap = ErrorMap(m, net.node_names)
    rng = np.random.default_rng(seed)
    net_vals = {**vals, **follow_series(m, t, vals)}
    names = list(net_vals)
    cols = [net_vals[k] for k in names]

    def inputs_at(k: int) -> dict[str, float]:
        return {name: float(c[k]) for name, c in zip(names, cols)}

    u = inputs_at(0)
    x = initial_temperatures(net, u)
    x_ref = x.copy()
    X = np.empty((n_t, net.n))
    TB = np.empty((n_t, len(net.boundary_names)))
    R = np.empty((n_t, len(sensors.ids)))
    done = 0
    for k in range(n_t):
        u = inputs_at(k)
        X[k] = x
        TB[k] = net.boundary_temperatures(u)
        R[k] = sensors.read(x, TB[k], 0.0 if k == 0 else t[k] - t[k - 1], rng, float(t[k]))
        if k + 1 < n_t:
            x = net.step(x, u, t[k], t[k + 1] - t[k])
        if progress is not None and (k + 1) % 1000 == 0:
            progress(k + 1 - done)
            done = k + 1
    if progress is not None and n_t > done:
        progress(n_t - done)
    E = emap.errors(X, x_ref)
    return SimulationResult(
        machine=m, time_s=t.copy(), inputs={k: v.copy() for k, v in vals.items()},
        sensors={sid: R[:, j].copy() for j, sid in enumerate(sensors.ids)},
        errors={e: E[:, j].copy() for j, e in enumerate(emap.names)},
        node_temperatures=X, boundary_temperatures=TB, name=timeline.name,
        events=list(timeline.events))
