"""When the model node saves its state periodically: off the temperature-to-offsets path.

A save is due at instant t once ``period_s`` of model time passed since the last one. Saving
right after t's prediction would take the CPU while the bridge computes and writes t's offsets
(the bridge's documentation, latency section), so the save waits until the bridge's offsets answering t
have arrived; the node withholds its lock-step ack of t until then. Nothing waits forever: after
``wait_s`` wall seconds without those offsets the save runs anyway. A node that has never seen
offsets (no bridge) saves at once. A probing cycle at t saves when it ends, so no second save is
scheduled for t. No ROS here: the node feeds events and wall time in.
"""
from __future__ import annotations

import enum
import math


class SaveNow(enum.Enum):
    NO = "no"           # not due, or a probing cycle will save
    NOW = "now"         # save before acknowledging t
    DEFERRED = "later"  # save once the offsets for t arrive (or at the deadline)


class SaveSchedule:
    """The periodic save's timing (see the module docstring)."""

    def __init__(self, period_s: float, wait_s: float):
        for name, v in (("save_period_s", period_s), ("offsets_wait_s", wait_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"SaveSchedule.{name}: {v!r} must be a finite number >= 0")
        self.period_s = float(period_s)
        self.wait_s = float(wait_s)
        self.last_save_t = -math.inf
        self.pending_t: float | None = None
        self.deadline_s = math.inf

    @property
    def pending(self) -> bool:
        return self.pending_t is not None

    def on_instant(self, t_s: float, now_s: float, offsets_seen: bool, offsets_stamp_s: float,
                   probing: bool) -> SaveNow:
        """A new instant ``t_s`` was predicted; ``probing``: a cycle is running (it saves at its end)."""
        if self.pending or probing or t_s - self.last_save_t < self.period_s:
            return SaveNow.NO
        if not offsets_seen or offsets_stamp_s >= t_s or self.wait_s == 0:
            return SaveNow.NOW
        self.pending_t = float(t_s)
        self.deadline_s = now_s + self.wait_s
        return SaveNow.DEFERRED

    def offsets_arrived(self, stamp_s: float) -> bool:
        """True when the deferred save may run now (the bridge answered its instant)."""
        return self.pending and stamp_s >= self.pending_t

    def overdue(self, now_s: float) -> bool:
        """True when the deferred save must run now without the offsets (deadline passed)."""
        return self.pending and now_s >= self.deadline_s

    def saved(self, t_s: float) -> None:
        """The state was saved at model time ``t_s`` (periodic, after probing or at shutdown)."""
        self.last_save_t = max(self.last_save_t, float(t_s))
        self.pending_t = None
        self.deadline_s = math.inf
