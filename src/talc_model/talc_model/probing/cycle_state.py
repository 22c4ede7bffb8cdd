"""The probing state machine: one probing cycle at a time, explicit states, no ROS.

A cycle for instant t goes IDLE -> (WAIT_OFFSETS) -> WAIT_ACCEPT -> RUNNING -> IDLE. Every
transition that needs the shell to act returns an :class:`Action`; every end of a cycle
returns a :class:`ProbeOutcome`. Deadlines are in the caller's clock (wall time in the
node), so nothing waits for ever; events for another cycle than the current one are stale
and ignored (a result that arrives after its cycle timed out is never learned from).
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Mapping


class ProbeState(enum.Enum):
    IDLE = "idle"
    WAIT_OFFSETS = "wait_offsets"     # the compensation for t is not applied yet
    WAIT_ACCEPT = "wait_accept"       # goal sent, the server has not accepted it yet
    RUNNING = "running"               # accepted, waiting for the result


class Action(enum.Enum):
    NONE = "none"
    SEND_GOAL = "send_goal"           # capture the applied compensation and start the cycle now
    CANCEL_GOAL = "cancel_goal"       # the cycle timed out: cancel it at the server


@dataclass(frozen=True)
class ProbeOutcome:
    """The end of one cycle: ``measured`` (residual per component) on success, else ``reason``."""

    t_s: float
    success: bool
    measured: dict[str, float] = field(default_factory=dict)
    applied: dict[str, float] = field(default_factory=dict)
    reason: str = ""


class ProbingError(RuntimeError):
    """A transition that the current state does not allow (a bug in the caller)."""


class ProbingStateMachine:
    """States and transitions of one probing cycle at a time (see the module docstring)."""

    def __init__(self, offsets_wait_s: float = 2.0, result_wait_s: float = 600.0):
        for name, v in (("offsets_wait_s", offsets_wait_s), ("result_wait_s", result_wait_s)):
            if not (isinstance(v, (int, float)) and v >= 0 and math.isfinite(v)):
                raise ValueError(f"ProbingStateMachine.{name}: {v!r} must be a finite number >= 0")
        self.offsets_wait_s = float(offsets_wait_s)
        self.result_wait_s = float(result_wait_s)
        self.state = ProbeState.IDLE
        self.t_s: float | None = None
        self.applied: dict[str, float] = {}
        self.deadline_s = math.inf
        self.started = 0
        self.failed = 0
        self.timed_out = 0

    @property
    def busy(self) -> bool:
        return self.state is not ProbeState.IDLE

    def request(self, t_s: float, now_s: float, wait_for_offsets: bool = False) -> Action:
        """Start a cycle for ``t_s``: SEND_GOAL now, or NONE while the offsets for t are awaited."""
        if self.busy:
            raise ProbingError(f"probing at {t_s:.0f} s requested while the cycle at {self.t_s:.0f} s is "
                               f"{self.state.value}")
        self.t_s = float(t_s)
        self.started += 1
        if wait_for_offsets:
            self.state = ProbeState.WAIT_OFFSETS
            self.deadline_s = now_s + self.offsets_wait_s
            return Action.NONE
        return self._ready(now_s)

    def offsets_arrived(self, stamp_s: float, now_s: float) -> Action:
        """The bridge answered up to ``stamp_s``: SEND_GOAL once it covers the cycle's instant."""
        if self.state is ProbeState.WAIT_OFFSETS and stamp_s >= self.t_s:
            return self._ready(now_s)
        return Action.NONE

    def goal_sent(self, applied: Mapping[str, float]) -> None:
        """The shell sent the goal; ``applied`` is the compensation the probe will see."""
        self._expect(ProbeState.WAIT_ACCEPT, "goal_sent")
        self.applied = dict(applied)

    def accepted(self, t_s: float) -> bool:
        """The server accepted the goal of the cycle at ``t_s`` (False: stale, ignored)."""
        if not self._current(t_s):
            return False
        self._expect(ProbeState.WAIT_ACCEPT, "accepted")
        self.state = ProbeState.RUNNING
        return True

    def succeeded(self, t_s: float, measured: Mapping[str, float]) -> ProbeOutcome | None:
        """The cycle at ``t_s`` measured ``measured`` (the residual); None if stale."""
        if not self._current(t_s):
            return None
        out = ProbeOutcome(self.t_s, True, dict(measured), dict(self.applied))
        self._reset()
        return out

    def failed_cycle(self, t_s: float | None, reason: str) -> ProbeOutcome | None:
        """The cycle at ``t_s`` (None: the current one) failed; None if stale or idle."""
        if not self.busy or (t_s is not None and not self._current(t_s)):
            return None
        out = ProbeOutcome(self.t_s, False, {}, dict(self.applied), reason)
        self.failed += 1
        self._reset()
        return out

    def tick(self, now_s: float) -> tuple[Action, ProbeOutcome | None]:
        """Check the deadline: late offsets -> SEND_GOAL with the last ones; a late result ->
        CANCEL_GOAL and a failed outcome."""
        if not self.busy or now_s < self.deadline_s:
            return Action.NONE, None
        if self.state is ProbeState.WAIT_OFFSETS:
            return self._ready(now_s), None
        self.timed_out += 1
        out = self.failed_cycle(None, f"no probing result within {self.result_wait_s:g} s (cancelled)")
        return Action.CANCEL_GOAL, out

    # ------------------------------------------------------------------ internals
    def _ready(self, now_s: float) -> Action:
        self.state = ProbeState.WAIT_ACCEPT
        self.deadline_s = now_s + self.result_wait_s
        return Action.SEND_GOAL

    def _current(self, t_s: float) -> bool:
        return self.busy and self.t_s == t_s

    def _expect(self, state: ProbeState, what: str) -> None:
        if self.state is not state:
            raise ProbingError(f"{what}: the probing cycle is {self.state.value}, expected {state.value}")

    def _reset(self) -> None:
        self.state = ProbeState.IDLE
        self.t_s = None
        self.applied = {}
        self.deadline_s = math.inf
