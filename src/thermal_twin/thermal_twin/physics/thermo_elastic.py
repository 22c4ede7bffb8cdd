"""Thermo-elastic map: node temperatures -> thermal error components.

Deformation is quasi-static compared with heat transfer (thesis ch. 3), so each error is
a linear combination of the nodes' temperature rises since the reference instant:
``E_m = offset_m + sum_i g_mi (T_i - T_i,ref)``, g in um/K (linear errors) or um/m per K
(angular errors). A node stands for a body whose mean temperature drives an elongation
alpha * L * dT, so g ~ 11.5 um/(m K) times an effective length.
"""
from __future__ import annotations

import numpy as np

from thermal_twin.machine.schema import Machine


class ErrorMap:
    def __init__(self, machine: Machine, node_names: list[str]):
        self.names = list(machine.errors)
        self.units = [machine.errors[e].unit for e in self.names]
        idx = {n: i for i, n in enumerate(node_names)}
        self.gain = np.zeros((len(self.names), len(node_names)))
        self.offset = np.array([machine.errors[e].offset for e in self.names])
        for j, e in enumerate(self.names):
            for node, g in machine.errors[e].terms:
                self.gain[j, idx[node]] += g

    def errors(self, node_temps: np.ndarray, reference_temps: np.ndarray) -> np.ndarray:
        """Error components for node temperatures (vector or rows of a matrix)."""
        return (np.asarray(node_temps) - reference_temps) @ self.gain.T + self.offset
