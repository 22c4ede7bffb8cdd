"""Execution of a cycle plan through a probe backend: feedback per point, cancel, timeout.

Execution stops at the first problem. The point is to keep a failing machine from
running on, the way a CNC probing cycle alarms:

* a missing trigger (the probe did not touch within the move's travel);
* a backend error (no connection, no answer in time);
* a cancel request, checked before every move;
* the timeout: the cycle's elapsed time on the machine's clock (simulated time on the
  twin) would exceed ``timeout_s`` with the next move.

Elapsed time is the larger of the planned time of the moves done and the span of the
machine's trigger stamps (a slow machine shows in its stamps).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from probe_cycle.cycle_plan import CyclePlan, TouchMove
from probe_cycle.probe_backend import ProbeBackend, ProbeBackendError, TouchReply


@dataclass
class Execution:
    replies: list[TouchReply] = field(default_factory=list)
    elapsed_s: float = 0.0
    failure: str | None = None     # why execution stopped early (None: all moves done)
    canceled: bool = False


PointCallback = Callable[[int, int, TouchMove, TouchReply], None]


def execute_plan(plan: CyclePlan, backend: ProbeBackend, timeout_s: float,
                 on_point: PointCallback | None = None,
                 cancel_requested: Callable[[], bool] | None = None) -> Execution:
    ex = Execution()
    planned = 0.0
    t0 = None
    total = len(plan.moves)
    for i, move in enumerate(plan.moves):
        if cancel_requested is not None and cancel_requested():
            ex.canceled = True
            ex.failure = f"canceled before {move.stage} ({i} of {total} points done)"
            return ex
        if ex.elapsed_s + move.duration_s > timeout_s + 1e-9:
            ex.failure = (f"timeout: {ex.elapsed_s:.1f} s elapsed, {move.stage} would end "
                          f"after the limit of {timeout_s:g} s ({i} of {total} points done)")
            return ex
        try:
            reply = backend.touch(move)
        except ProbeBackendError as exc:
            ex.failure = f"probe backend '{backend.name}' failed at {move.stage}: {exc}"
            return ex
        planned += move.duration_s
        if t0 is None:
            t0 = reply.stamp_s - move.duration_s
        ex.replies.append(reply)
        ex.elapsed_s = max(planned, reply.stamp_s - t0)
        if on_point is not None:
            on_point(i + 1, total, move, reply)
        if not reply.triggered:
            extra = f" ({reply.message})" if reply.message else ""
            ex.failure = (f"missing trigger at {move.stage}: no contact within "
                          f"{move.max_travel_mm:g} mm from {list(move.start_mm)}{extra}")
            return ex
        if ex.elapsed_s > timeout_s + 1e-9:
            ex.failure = (f"timeout: {ex.elapsed_s:.1f} s elapsed at {move.stage}, above the "
                          f"limit of {timeout_s:g} s")
            return ex
    return ex
