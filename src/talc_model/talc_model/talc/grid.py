"""TALC's uniform model grid (``model_step_s``): inputs, and measured or predicted outputs, per
sample, and the model's state estimate of each output (``x``: the observer's, which a probe
corrects but does not replace; ``talc_model.arx.observer``); grows by doubling; its state is
part of the TALC model's state. No rclpy here.
"""
from __future__ import annotations

import math

import numpy as np


class ModelGrid:
    """The uniform model grid: inputs, outputs (measured or predicted) per sample."""

    def __init__(self, n_inputs: int, n_outputs: int, capacity: int = 256):
        self.n = 0
        self.u = np.zeros((capacity, n_inputs))
        self.y = np.full((capacity, n_outputs), np.nan)
        self.measured = np.zeros((capacity, n_outputs), dtype=bool)
        self.x = np.full((capacity, n_outputs), np.nan)   # the model's state estimate per sample

    def append(self, u_row: np.ndarray) -> int:
        if self.n == self.u.shape[0]:
            cap = 2 * self.u.shape[0]
            self.u = np.resize(self.u, (cap, self.u.shape[1]))
            y = np.full((cap, self.y.shape[1]), np.nan)
            y[: self.n] = self.y[: self.n]
            self.y = y
            m = np.zeros((cap, self.y.shape[1]), dtype=bool)
            m[: self.n] = self.measured[: self.n]
            self.measured = m
            x = np.full((cap, self.y.shape[1]), np.nan)
            x[: self.n] = self.x[: self.n]
            self.x = x
        self.u[self.n] = u_row
        self.y[self.n] = np.nan
        self.x[self.n] = np.nan
        self.measured[self.n] = False
        self.n += 1
        return self.n - 1

    def to_state(self) -> dict:
        return {"u": self.u[: self.n].tolist(), "y": _rows(self.y[: self.n]), "x": _rows(self.x[: self.n]),
                "measured": self.measured[: self.n].astype(int).tolist()}

    @classmethod
    def from_state(cls, d: dict, n_inputs: int, n_outputs: int) -> "ModelGrid":
        u = np.asarray(d["u"], dtype=float).reshape(-1, n_inputs)
        y = np.asarray([[np.nan if v is None else v for v in row] for row in d["y"]],
                       dtype=float).reshape(-1, n_outputs)
        m = np.asarray(d["measured"], dtype=bool).reshape(-1, n_outputs)
        # a state saved before the observer: the state estimate was the output history itself
        x = y.copy() if d.get("x") is None else \
            np.asarray([[np.nan if v is None else v for v in row] for row in d["x"]], dtype=float).reshape(-1, n_outputs)
        if not (u.shape[0] == y.shape[0] == m.shape[0] == x.shape[0]):
            raise ValueError(f"TALC state 'grid': u has {u.shape[0]} rows, y {y.shape[0]}, measured {m.shape[0]}, "
                             f"x {x.shape[0]}")
        g = cls(n_inputs, n_outputs, max(256, u.shape[0]))
        g.n = u.shape[0]
        g.u[: g.n], g.y[: g.n], g.measured[: g.n], g.x[: g.n] = u, y, m, x
        return g


def _rows(a: np.ndarray) -> list:
    return [[None if not math.isfinite(v) else v for v in row] for row in a.tolist()]
