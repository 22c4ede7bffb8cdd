"""When the online learner learns: every ``every_h`` hours of model time from the first instant it
saw, and on demand; one learning at a time. A due time that passes while a learning runs is kept
and served when it ends (several collapse into one), so the schedule never piles up jobs. No rclpy.
"""
from __future__ import annotations

import math


class LearnSchedule:
    """The learner's schedule in model time (s). ``every_h`` 0: on demand only."""

    def __init__(self, every_h: float):
        if not (math.isfinite(every_h) and every_h >= 0.0):
            raise ValueError(f"learn_every_h: {every_h!r} must be a number of hours >= 0")
        self.every_s = every_h * 3600.0
        self.t0: float | None = None
        self.next_due: float = math.inf
        self.pending: str = ""           # why a learning is owed ("" = none)

    def observe(self, t_s: float) -> None:
        """The model has reached ``t_s``: start the clock at the first instant, mark a due time."""
        if self.t0 is None:
            self.t0 = t_s
            self.next_due = t_s + self.every_s if self.every_s > 0 else math.inf
        if t_s >= self.next_due:
            self.pending = self.pending or f"schedule (every {self.every_s / 3600.0:g} h)"
            while self.next_due <= t_s:
                self.next_due += self.every_s

    def request(self) -> None:
        """A learning on demand (the service)."""
        self.pending = "on demand"

    def take(self, busy: bool) -> str:
        """Why to start a learning now ("" = not now): something is owed and none is running."""
        if busy or not self.pending or self.t0 is None:
            return ""
        why, self.pending = self.pending, ""
        return why

    def hours(self, t_s: float) -> float:
        """Hours of model time since the first instant."""
        return 0.0 if self.t0 is None else (t_s - self.t0) / 3600.0
