"""Fault injection for reliability tests and ``thermal-comp bench faults`` (no rclpy import).

Three kinds of tools, all plain Python/numpy:

- **sensor faults** on a stream of raw readings (:class:`SensorFault`, :func:`inject`):
  NaN, out of range, stuck value, spike, a sensor that disappears, and late / out-of-order
  delivery of whole frames (:func:`reorder_late`);
- **safety checks** on what reached a CNC (:func:`offset_violations`): every step of the
  applied offsets within the rate limit (``max_rate * min(dt, max_step) + tolerance``) and
  within the absolute limit;
- **process kills** of a running graph under the launcher (:class:`KillPlan`): ``kill -9``
  of a node's whole process group at a simulated instant, then the launcher's restart
  policy takes over; :func:`run_killed_graph` runs the demo graph with such a plan.

The policies these tools check are documented in docs/reliability.md.
"""
from __future__ import annotations

import math
import os
import signal
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

FAULT_KINDS = ("nan", "out_of_range", "stuck", "spike", "disappear")


@dataclass(frozen=True)
class SensorFault:
    """One fault of one sensor over ``[t_start_s, t_end_s)`` (simulated time).

    ``nan``: the value reads NaN; ``out_of_range``: the value reads ``value`` (a reading
    outside the sensor's range); ``stuck``: the value freezes at the first faulty reading;
    ``spike``: ``value`` is added (one reading when the window holds one sample);
    ``disappear``: the sensor is missing from the frame.
    """

    sensor_id: str
    kind: str
    t_start_s: float
    t_end_s: float = math.inf
    value: float = 0.0

    def __post_init__(self):
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"SensorFault.kind: {self.kind!r} is not one of {list(FAULT_KINDS)}")
        if not self.t_end_s > self.t_start_s:
            raise ValueError(f"SensorFault {self.sensor_id}: t_end_s {self.t_end_s!r} must be after "
                             f"t_start_s {self.t_start_s!r}")

    def active(self, t_s: float) -> bool:
        return self.t_start_s <= t_s < self.t_end_s


class FaultInjector:
    """Applies :class:`SensorFault` s to frames ``{sensor_id: value}`` in time order."""

    def __init__(self, faults: Iterable[SensorFault]):
        self.faults = list(faults)
        self._stuck: dict[int, float] = {}
        self.injected = 0          # readings altered or removed

    def apply(self, t_s: float, readings: Mapping[str, float]) -> dict[str, float]:
        out = dict(readings)
        for i, f in enumerate(self.faults):
            if not f.active(t_s) or f.sensor_id not in out:
                continue
            self.injected += 1
            if f.kind == "nan":
                out[f.sensor_id] = math.nan
            elif f.kind == "out_of_range":
                out[f.sensor_id] = float(f.value)
            elif f.kind == "stuck":
                out[f.sensor_id] = self._stuck.setdefault(i, out[f.sensor_id])
            elif f.kind == "spike":
                out[f.sensor_id] = out[f.sensor_id] + float(f.value)
            else:  # disappear
                del out[f.sensor_id]
        return out


def inject(times_s: Sequence[float], frames: Sequence[Mapping[str, float]],
           faults: Iterable[SensorFault]) -> list[dict[str, float]]:
    """The frames with ``faults`` applied (a new list; the input is not changed)."""
    inj = FaultInjector(faults)
    return [inj.apply(float(t), fr) for t, fr in zip(times_s, frames)]


def reorder_late(n: int, late: Mapping[int, int]) -> list[int]:
    """Delivery order of ``n`` frames when frame ``i`` arrives ``late[i]`` positions late.

    ``reorder_late(5, {1: 2})`` -> ``[0, 2, 3, 1, 4]``: frame 1 arrives after frames 2 and 3
    (out of order). Every index appears exactly once.
    """
    keys = [(i + late.get(i, 0) + (0.5 if late.get(i, 0) else 0.0), i) for i in range(n)]
    return [i for _, i in sorted(keys)]


# --------------------------------------------------------------------------------------
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
            allow = max_rate_um_per_s * dt + tolerance_um
            if prev_t is None and prev == 0.0 and start_um is None:
                allow = max(allow, tolerance_um)
            if abs(vi - prev) > allow:
                out.append(OffsetViolation(axis, float(ti), prev, float(vi), allow, "rate limit"))
            prev, prev_t = float(vi), float(ti)
    return out


# --------------------------------------------------------------------------------------
@dataclass
class Kill:
    """``kill -9`` of node ``node`` once simulated time reaches ``at_sim_s``."""

    node: str
    at_sim_s: float
    done_wall: float | None = None
    pid: int | None = None
    restarted_pid: int | None = None


@dataclass
class KillPlan:
    """Kills to perform while a graph runs; call :meth:`poll` from the supervision loop."""

    kills: list[Kill] = field(default_factory=list)

    def poll(self, launcher, sim_s: float) -> None:
        import time
        by_name = {mp.node.name: mp for mp in launcher.processes}
        for k in self.kills:
            mp = by_name.get(k.node)
            if mp is None:
                raise ValueError(f"KillPlan: no node named {k.node!r} (have {sorted(by_name)})")
            if k.done_wall is None and sim_s >= k.at_sim_s and mp.running():
                k.pid = mp.pid
                try:
                    os.killpg(mp.pid, signal.SIGKILL)   # the node and anything it started
                except ProcessLookupError:
                    continue
                k.done_wall = time.monotonic()
            elif k.done_wall is not None and k.restarted_pid is None and mp.running() and mp.pid != k.pid:
                k.restarted_pid = mp.pid

    @property
    def all_done(self) -> bool:
        return all(k.done_wall is not None for k in self.kills)
