"""Sensor faults on a stream of raw readings, and late / out-of-order frame delivery.

NaN, out of range, stuck value, spike, a sensor that disappears (:class:`SensorFault`,
:func:`inject`); :func:`reorder_late` gives the delivery order of late frames. The policies
these faults check are in docs/reliability.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

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
        self.counts = [0] * len(self.faults)   # per fault

    def apply(self, t_s: float, readings: Mapping[str, float]) -> dict[str, float]:
        out = dict(readings)
        for i, f in enumerate(self.faults):
            if not f.active(t_s) or f.sensor_id not in out:
                continue
            self.injected += 1
            self.counts[i] += 1
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
