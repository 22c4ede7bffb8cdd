"""A message's stamp checked against the receiving node's clock before it is acted on (ROS-free).

A stamp is refused when it is not finite, when it is more than ``max_ahead_s`` ahead of the
node's clock (the graph's clock: /clock with ``use_sim_time``, wall time otherwise), or, on a
stream whose stamps only move forward, when it is behind the last accepted one (an equal stamp
is a re-sent instant and passes). A refused message must not move a model's clock, reach a
saved state or step a bridge's envelope: one forged stamp far ahead would otherwise make every
honest message after it "late" until the graph caught up.

Refusals are counted per kind. A burst (refusals until ``quiet`` stamps in a row were accepted
again) is logged once: :attr:`StampCheck.log` marks its first refusal, and
:attr:`StampCheck.burst_over` the acceptance that ends it.

Without a clock (``clock_now_s`` None: simulated time before the first /clock) only the
non-finite and behind tests apply; :func:`graph_clock_s` gives None for a clock reading 0.

The bound: a node may handle the data of instant t_k before the /clock of t_k (separate
topics), so a lock-step graph's stamps legitimately lead a node's clock by one simulation step
(at most :data:`SIM_MAX_AHEAD_S`); probing only moves /clock ahead of the stamps. On wall time
the lead is the clock skew between hosts (:data:`WALL_MAX_AHEAD_S`).
"""
from __future__ import annotations

import enum
import itertools
import math
from dataclasses import dataclass
from typing import Callable, Iterable

#: default bound on wall time: clock skew between the hosts of a cell, s
WALL_MAX_AHEAD_S = 60.0
#: default bound on simulated time: machine_sim's largest step (a node's /clock may lag one), s
SIM_MAX_AHEAD_S = 3600.0
#: orders refusals across the guards of a node (the newest one goes on /diagnostics)
_REFUSALS = itertools.count(1)


class Refusal(enum.Enum):
    AHEAD = "ahead"              # beyond the node's clock + max_ahead_s
    BEHIND = "behind"            # before the last accepted stamp of a forward-only stream
    NON_FINITE = "non_finite"    # NaN or infinite


@dataclass(frozen=True)
class StampCheck:
    """The verdict on one stamp."""

    refusal: Refusal | None      # None: accepted
    log: bool = False            # the first refusal of a burst: the caller says it once
    burst_over: bool = False     # this acceptance ended a burst of refusals
    text: str = ""               # one line naming the stream, the stamp and why (refused only)

    @property
    def accepted(self) -> bool:
        return self.refusal is None


def default_max_ahead_s(max_ahead_s: float, sim_time: bool) -> float:
    """The bound a node applies: ``max_ahead_s``, or for 0 the default of its clock."""
    if max_ahead_s > 0:
        return float(max_ahead_s)
    return SIM_MAX_AHEAD_S if sim_time else WALL_MAX_AHEAD_S


def graph_clock_s(now_ns: int) -> float | None:
    """A node's clock reading in s; None while it reads 0 (simulated time, no /clock yet)."""
    return None if now_ns == 0 else now_ns * 1e-9


class StampGuard:
    """Checks the stamps of one stream (a topic as one node receives it)."""

    def __init__(self, stream: str, max_ahead_s: float, *, forward_only: bool = True, quiet: int = 10):
        if not (math.isfinite(max_ahead_s) and max_ahead_s > 0):
            raise ValueError(f"max_ahead_s: {max_ahead_s!r} must be a finite number > 0")
        if quiet < 1:
            raise ValueError(f"quiet: {quiet!r} must be >= 1")
        self.stream = stream
        self.max_ahead_s = float(max_ahead_s)
        self.forward_only = forward_only
        self.quiet = int(quiet)
        self.counts = {r: 0 for r in Refusal}
        self.last_accepted_s: float | None = None
        self.last_refusal = ""           # the text of the newest refusal
        self.last_refusal_no = 0         # its place among every guard's refusals
        self.in_burst = False
        self._accepted_in_row = 0

    @property
    def refused(self) -> int:
        return sum(self.counts.values())

    def check(self, stamp_s: float, clock_now_s: float | None) -> StampCheck:
        """Accept ``stamp_s`` [s] or say why not; ``clock_now_s``: the node's clock (None: none yet)."""
        refusal, why = self._verdict(stamp_s, clock_now_s)
        if refusal is None:
            self.last_accepted_s = stamp_s if self.last_accepted_s is None else max(self.last_accepted_s, stamp_s)
            self._accepted_in_row += 1
            over = self.in_burst and self._accepted_in_row >= self.quiet
            if over:
                self.in_burst = False
            return StampCheck(None, burst_over=over)
        self.counts[refusal] += 1
        self._accepted_in_row = 0
        text = (f"{self.stream}: message stamped {stamp_s!r} s refused, {why} "
                f"({self.refused} refused so far; further refusals of this burst are counted, not logged)")
        self.last_refusal, self.last_refusal_no = text, next(_REFUSALS)
        first = not self.in_burst
        self.in_burst = True
        return StampCheck(refusal, log=first, text=text)

    def _verdict(self, stamp_s: float, clock_now_s: float | None) -> tuple[Refusal | None, str]:
        if not math.isfinite(stamp_s):
            return Refusal.NON_FINITE, "the stamp is not finite"
        if clock_now_s is not None and stamp_s - clock_now_s > self.max_ahead_s:
            return Refusal.AHEAD, (f"{stamp_s - clock_now_s:.3f} s ahead of the node's clock "
                                   f"({clock_now_s:.3f} s; bound {self.max_ahead_s:g} s)")
        if self.forward_only and self.last_accepted_s is not None and stamp_s < self.last_accepted_s:
            return Refusal.BEHIND, f"behind the last accepted stamp {self.last_accepted_s:.3f} s"
        return None, ""


def stamp_values(guards: Iterable[StampGuard]) -> dict[str, object]:
    """The ``/diagnostics`` values of a node's guards: refusals per kind, the newest one."""
    guards = list(guards)
    values: dict[str, object] = {f"stamps_refused_{r.value}": sum(g.counts[r] for g in guards)
                                 for r in Refusal}
    newest = max(guards, key=lambda g: g.last_refusal_no, default=None)
    values["last_stamp_refused"] = newest.last_refusal if newest is not None and newest.last_refusal else "none"
    return values


def admit(guard: StampGuard, stamp_s: float, clock_now_s: float | None,
          warn: Callable[[str], None], note: str = "") -> tuple[StampCheck, bool]:
    """Check one stamp with ``guard``: (the check, the node's ``stamps`` status is to be
    refreshed); the first refusal of a burst is said through ``warn`` (``note`` appended)."""
    check = guard.check(stamp_s, clock_now_s)
    if check.log:
        warn(check.text + note)
    return check, (not check.accepted or check.burst_over)


def stamp_status(guards: Iterable[StampGuard], **extra: object) -> tuple[str, str, dict[str, object]]:
    """A node's ``/diagnostics`` status ``stamps``: (level, message, values)."""
    guards = list(guards)
    burst = any(g.in_burst for g in guards)
    return ("WARN" if burst else "OK",
            "refusing messages stamped off the graph's clock" if burst else "stamps on the graph's clock",
            {**extra, **stamp_values(guards)})
