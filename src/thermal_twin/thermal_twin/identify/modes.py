"""The thermal modes of an identified lumped twin: its time constants at rest (every machine input
zero, so only the links' base conductances; a speed only adds convection and makes modes faster,
so this is the slowest case). A recording of length T shows a mode with time constant tau > T
only as a slope: its time constant and its gain trade off freely, and a twin that keeps such a
mode extrapolates it beyond T with whatever the fit happened to choose. No rclpy.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np


def conductance_matrix(spec: Mapping) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(node names, capacities C, conductance matrix G) of ``spec`` at rest: dT/dt = -C^-1 G T + ..."""
    nodes = list(spec["nodes"])
    idx = {n: i for i, n in enumerate(nodes)}
    cap = np.array([float(spec["nodes"][n]["capacity"]) for n in nodes])
    g = np.zeros((len(nodes), len(nodes)))
    for link in spec.get("links", {}).values():
        a, b = link["between"]
        k = float(link.get("conductance", 0.0))
        for x, y in ((a, b), (b, a)):
            if x in idx:
                g[idx[x], idx[x]] += k
                if y in idx:
                    g[idx[x], idx[y]] -= k
    return nodes, cap, g


def time_constants_h(spec: Mapping) -> np.ndarray:
    """The twin's time constants at rest in hours, slowest first (inf for a node with no path to a
    boundary: it integrates its heat)."""
    _, cap, g = conductance_matrix(spec)
    # C^-1/2 G C^-1/2 is symmetric with the same eigenvalues as C^-1 G
    s = 1.0 / np.sqrt(cap)
    lam = np.linalg.eigvalsh(s[:, None] * g * s[None, :])
    with np.errstate(divide="ignore"):
        tau = np.where(lam > 1e-15, 1.0 / np.maximum(lam, 1e-300), np.inf) / 3600.0
    return np.sort(tau)[::-1]


def slowest_mode_h(spec: Mapping) -> float:
    return float(time_constants_h(spec)[0])
