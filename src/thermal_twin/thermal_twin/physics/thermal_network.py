"""The lumped-parameter thermal network of a machine, integrated exactly.

Node temperatures x [degC] obey ``C x' = -K(u) x + Kb(u) Tb(u) + P(u, t)``: C the heat
capacities, K(u) the conductance (Laplacian) matrix including the links to boundaries,
Kb(u) the node-boundary conductances, Tb the boundary temperatures and P the heat sources.
The conductances depend on the inputs only through the links' ``varies_with`` terms, so a
step with piecewise-constant inputs is exact with the zero-order-hold discretisation

    x(t+dt) = Phi x(t) + Psi f,   Phi = exp(A dt),  Psi = int_0^dt exp(A s) ds,
    A = -C^-1 K,  f = C^-1 (Kb Tb + P),

computed with one matrix exponential of an augmented matrix (which also yields the exact
time integral of x over the step, used for the energy balance) and cached per conductance
regime and step length. Periodic source terms are evaluated at the middle of the step.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.linalg import expm

from thermal_twin.machine.schema import Machine, MachineSpecError


@dataclass(frozen=True)
class StepMatrices:
    """Exact one-step maps for a constant-conductance regime and step length."""

    phi: np.ndarray      # x(dt) = phi x0 + psi f
    psi: np.ndarray
    theta: np.ndarray    # int_0^dt x ds = theta x0 + omega f
    omega: np.ndarray


@dataclass(frozen=True)
class StepEnergy:
    """Heat flows integrated over one step, in joules."""

    stored: float          # change of sum(C_i x_i)
    from_sources: float    # heat put in by the sources
    to_boundaries: float   # heat given to the boundaries (ambient, coolant, ...)


class ThermalNetwork:
    """Compiled matrices of a :class:`Machine`'s thermal network."""

    def __init__(self, machine: Machine, cache_size: int = 512):
        self.machine = machine
        self.node_names = list(machine.nodes)
        self.boundary_names = list(machine.boundaries)
        follows = [b for b, s in machine.boundaries.items() if s.temperature is None]
        if follows:
            raise MachineSpecError(f"boundaries.{follows[0]}: follows another temperature; the network takes the "
                                   "machine lowered (thermal_twin.physics.boundary_follow.lowered), as simulate does")
        self.n = len(self.node_names)
        self._ni = {n: i for i, n in enumerate(self.node_names)}
        self._bi = {b: i for i, b in enumerate(self.boundary_names)}
        self.capacity = np.array([machine.nodes[n].capacity for n in self.node_names])
        self._inv_c = 1.0 / self.capacity
        self.input_names = list(machine.inputs)
        self._defaults = {k: s.default for k, s in machine.inputs.items()}
        # links split into constant ones (folded into base matrices) and input-dependent ones
        self._links = list(machine.links.values())
        self._varying = [l for l in self._links if l.varies_with]
        self._cache: OrderedDict = OrderedDict()
        self._regimes: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self._cache_size = cache_size
        self._check_connected()

    # ----------------------------------------------------------------------------------
    def _check_connected(self) -> None:
        """Every node needs a conductive path to some boundary, else no steady state exists."""
        adj: dict[str, set[str]] = {p: set() for p in self.node_names + self.boundary_names}
        for l in self._links:
            adj[l.a].add(l.b)
            adj[l.b].add(l.a)
        seen = set(self.boundary_names)
        frontier = list(self.boundary_names)
        while frontier:
            p = frontier.pop()
            for q in adj[p]:
                if q not in seen:
                    seen.add(q)
                    frontier.append(q)
        lost = [n for n in self.node_names if n not in seen]
        if lost:
            raise MachineSpecError(f"nodes.{lost[0]}: {lost[0]!r} has no link path to any boundary "
                                   f"(isolated nodes: {lost})")

    def input_value(self, inputs: Mapping[str, float], name: str) -> float:
        v = inputs.get(name, self._defaults[name])
        return float(v)

    def link_conductances(self, inputs: Mapping[str, float]) -> np.ndarray:
        """Conductance of every link [W/K] for the given inputs (in ``machine.links`` order)."""
        g = np.empty(len(self._links))
        for j, l in enumerate(self._links):
            v = l.conductance
            for iname, per_unit, expo in l.varies_with:
                v += per_unit * abs(self.input_value(inputs, iname)) ** expo
            g[j] = v
        return g

    def regime_key(self, inputs: Mapping[str, float]) -> tuple:
        """The values that define the conductance regime (inputs of varying links)."""
        return tuple(self.input_value(inputs, i) for l in self._varying for i, _, _ in l.varies_with)

    def matrices(self, inputs: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """(K, Kb): node conductance matrix and node-boundary conductances for ``inputs``."""
        key = self.regime_key(inputs)
        hit = self._regimes.get(key)
        if hit is None:
            hit = self._build_matrices(inputs)
            if len(self._regimes) >= self._cache_size:
                self._regimes.clear()
            self._regimes[key] = hit
        return hit

    def _build_matrices(self, inputs: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        g = self.link_conductances(inputs)
        K = np.zeros((self.n, self.n))
        Kb = np.zeros((self.n, len(self.boundary_names)))
        for gj, l in zip(g, self._links):
            a_node, b_node = l.a in self._ni, l.b in self._ni
            if a_node and b_node:
                i, k = self._ni[l.a], self._ni[l.b]
                K[i, i] += gj
                K[k, k] += gj
                K[i, k] -= gj
                K[k, i] -= gj
            else:
                node, bnd = (l.a, l.b) if a_node else (l.b, l.a)
                i, b = self._ni[node], self._bi[bnd]
                K[i, i] += gj
                Kb[i, b] += gj
        return K, Kb

    def boundary_temperatures(self, inputs: Mapping[str, float]) -> np.ndarray:
        out = np.empty(len(self.boundary_names))
        for j, b in enumerate(self.boundary_names):
            t = self.machine.boundaries[b].temperature
            out[j] = self.input_value(inputs, t) if isinstance(t, str) else t
        return out

    def source_powers(self, inputs: Mapping[str, float], t_s: float) -> np.ndarray:
        """Heat input per node [W] at time ``t_s`` for ``inputs``."""
        p = np.zeros(self.n)
        for s in self.machine.sources.values():
            v = s.power
            if s.input is not None:
                v += s.coefficient * abs(self.input_value(inputs, s.input)) ** s.exponent
            if s.periodic_amplitude:
                v += s.periodic_amplitude * math.sin(2 * math.pi * (t_s - s.periodic_phase_s)
                                                     / s.periodic_period_s)
            p[self._ni[s.node]] += v
        return p

    # ----------------------------------------------------------------------------------
    def steady_state(self, inputs: Mapping[str, float], t_s: float = 0.0) -> np.ndarray:
        """Node temperatures at equilibrium for constant ``inputs``: K x = Kb Tb + P."""
        K, Kb = self.matrices(inputs)
        rhs = Kb @ self.boundary_temperatures(inputs) + self.source_powers(inputs, t_s)
        try:
            return np.linalg.solve(K, rhs)
        except np.linalg.LinAlgError:
            raise MachineSpecError(f"{self.machine.name}: no steady state for inputs {dict(inputs)}: "
                                   "some node has no conductance to a boundary at these inputs") from None

    def step_matrices(self, inputs: Mapping[str, float], dt: float) -> StepMatrices:
        """Exact ZOH maps for ``dt`` seconds in the regime of ``inputs`` (cached)."""
        key = (round(float(dt), 9), self.regime_key(inputs))
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        K, _ = self.matrices(inputs)
        n = self.n
        A = -self._inv_c[:, None] * K
        M = np.zeros((3 * n, 3 * n))
        M[:n, :n] = A
        M[:n, n:2 * n] = np.eye(n)
        M[2 * n:, :n] = np.eye(n)
        E = expm(M * dt)
        sm = StepMatrices(E[:n, :n].copy(), E[:n, n:2 * n].copy(),
                          E[2 * n:, :n].copy(), E[2 * n:, n:2 * n].copy())
        self._cache[key] = sm
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return sm

    def forcing(self, inputs: Mapping[str, float], t_s: float, dt: float) -> np.ndarray:
        """f = C^-1 (Kb Tb + P) for the step starting at ``t_s`` (sources at mid-step)."""
        _, Kb = self.matrices(inputs)
        return self._inv_c * (Kb @ self.boundary_temperatures(inputs)
                              + self.source_powers(inputs, t_s + 0.5 * dt))

    def step(self, x: np.ndarray, inputs: Mapping[str, float], t_s: float, dt: float) -> np.ndarray:
        """Node temperatures after ``dt`` seconds of constant ``inputs`` (exact)."""
        sm = self.step_matrices(inputs, dt)
        return sm.phi @ x + sm.psi @ self.forcing(inputs, t_s, dt)

    def step_energy(self, x: np.ndarray, inputs: Mapping[str, float], t_s: float,
                    dt: float) -> tuple[np.ndarray, StepEnergy]:
        """One exact step plus the heat flows integrated over it (for energy balances)."""
        sm = self.step_matrices(inputs, dt)
        f = self.forcing(inputs, t_s, dt)
        x1 = sm.phi @ x + sm.psi @ f
        x_int = sm.theta @ x + sm.omega @ f               # int_0^dt x ds, exact
        _, Kb = self.matrices(inputs)
        tb = self.boundary_temperatures(inputs)
        p = self.source_powers(inputs, t_s + 0.5 * dt)
        to_b = float(np.sum(Kb * (x_int[:, None] - dt * tb[None, :])))
        return x1, StepEnergy(stored=float(self.capacity @ (x1 - x)),
                              from_sources=float(p.sum() * dt), to_boundaries=to_b)
