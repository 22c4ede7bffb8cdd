"""A probe backend that breaks one touch of a probing cycle (outlier, missing trigger, error,
stalled clock), to check that the cycle fails instead of returning errors."""
from __future__ import annotations

import numpy as np

from probe_cycle.probe_backend import ProbeBackendError, TouchReply

class FaultyProbeBackend:
    """A probe backend that breaks one touch of a cycle: ``outlier`` (the skip position
    moved by ``value_um`` along the move), ``missing_trigger``, ``error`` (the backend
    raises), ``slow`` (the machine clock jumps by ``value_um`` seconds: a stalled cycle that
    runs into its timeout). Every other touch goes to ``inner``."""

    def __init__(self, inner, fault: str, at_touch: int = 3, value_um: float = 25.0):
        if fault not in ("outlier", "missing_trigger", "error", "slow"):
            raise ValueError(f"FaultyProbeBackend.fault: {fault!r} is not outlier, missing_trigger, error or slow")
        self.inner, self.fault, self.at_touch, self.value = inner, fault, int(at_touch), float(value_um)
        self.touches = 0
        self.name = f"faulty({getattr(inner, 'name', 'backend')})"
        self._clock_jump = 0.0

    def touch(self, move):
        i = self.touches
        self.touches += 1
        reply = self.inner.touch(move)
        if i != self.at_touch:
            return TouchReply(reply.triggered, reply.position_mm, reply.stamp_s + self._clock_jump, reply.message)
        if self.fault == "error":
            raise ProbeBackendError("injected: probe signal lost")
        if self.fault == "missing_trigger":
            return TouchReply(False, reply.position_mm, reply.stamp_s + self._clock_jump, "injected: no trigger")
        if self.fault == "slow":
            self._clock_jump += self.value
            return TouchReply(reply.triggered, reply.position_mm, reply.stamp_s + self._clock_jump, reply.message)
        d = np.asarray(move.direction, dtype=float)
        pos = np.asarray(reply.position_mm, dtype=float) + d / np.linalg.norm(d) * self.value * 1e-3
        return TouchReply(reply.triggered, pos, reply.stamp_s, reply.message)

    def close(self) -> None:
        self.inner.close()
