"""Safety checks on what reached a CNC: every step of the applied offsets within the rate
limit (``max_rate * min(dt, max_step) + tolerance``) and within the absolute limit, from a
sampled series (:func:`offset_violations`) or an emulator's write log (:func:`step_violations`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

@dataclass(frozen=True)
class OffsetViolation:
    """A step of the applied offsets that broke the envelope."""

    axis: str
    t_s: float
    previous_um: float
    applied_um: float
    allowed_step_um: float
    why: str

    def __str__(self) -> str:
        return (f"axis {self.axis} at t={self.t_s:.3f} s: {self.previous_um:+.4f} -> {self.applied_um:+.4f} um "
                f"({self.why}; allowed step {self.allowed_step_um:.4f} um)")


def offset_violations(times_s: Sequence[float], applied_um: Mapping[str, Sequence[float]],
                      max_rate_um_per_s: float, abs_limit_um: float, max_step_s: float = math.inf,
                      start_um: Mapping[str, float] | None = None,
                      tolerance_um: float = 1e-6) -> list[OffsetViolation]:
    """Every step of ``applied_um[axis]`` (sampled at ``times_s``) that moves faster than
    ``max_rate_um_per_s`` (the elapsed time capped at ``max_step_s``, as the envelope does)
    or exceeds ``abs_limit_um``. ``start_um`` is what the CNC held before the first sample
    (default 0). NaN samples (a write not confirmed) are skipped: the CNC kept the previous
    value. Samples at equal times must not change the value at all.
    """
    t = np.asarray(times_s, dtype=float)
    out: list[OffsetViolation] = []
    for axis, series in applied_um.items():
        v = np.asarray(series, dtype=float)
        if v.shape != t.shape:
            raise ValueError(f"applied_um[{axis!r}]: {v.size} samples for {t.size} times")
        prev = float((start_um or {}).get(axis, 0.0))
        prev_t = None
        for ti, vi in zip(t, v):
            if not math.isfinite(vi):
                continue
            if abs(vi) > abs_limit_um + tolerance_um:
                out.append(OffsetViolation(axis, float(ti), prev, float(vi), abs_limit_um, "absolute limit"))
            dt = 0.0 if prev_t is None else min(max(ti - prev_t, 0.0), max_step_s)
            allow = max_rate_um_per_s * dt + tolerance_um   # the first sample may not move at all
            if abs(vi - prev) > allow:
                out.append(OffsetViolation(axis, float(ti), prev, float(vi), allow, "rate limit"))
            prev, prev_t = float(vi), float(ti)
    return out


def written_offsets_um(write_log: Sequence[tuple[str, float]], axis: str, scale_um_per_unit: float = 1000.0
                       ) -> list[float]:
    """The offsets (um) written to ``axis``'s SD43900 node, in order, from an emulator write log."""
    suffix = f"TempComp.{axis}.SD43900"
    return [float(v) * scale_um_per_unit for nid, v in write_log if nid.endswith(suffix)]


def step_violations(values_um: Sequence[float], max_step_um: float, abs_limit_um: float, axis: str,
                    start_um: float = 0.0, tolerance_um: float = 1e-6) -> list[OffsetViolation]:
    """Consecutive values written to a CNC that differ by more than ``max_step_um`` (one
    envelope step's allowance) or exceed ``abs_limit_um``; index = write number."""
    out, prev = [], float(start_um)
    for i, v in enumerate(values_um):
        if abs(v) > abs_limit_um + tolerance_um:
            out.append(OffsetViolation(axis, float(i), prev, float(v), abs_limit_um, "absolute limit"))
        if abs(v - prev) > max_step_um + tolerance_um:
            out.append(OffsetViolation(axis, float(i), prev, float(v), max_step_um, "rate limit"))
        prev = float(v)
    return out
