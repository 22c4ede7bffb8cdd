"""Who machine_sim's lock-step waits for, and which acknowledgements count (ROS-free).

- An acknowledgement (``SimSync.processed_until``) of an instant the graph has not published
  is refused: counted, the first of a burst logged, never recorded as an acknowledgement
  (:class:`thermal_comp_common.stamp_guard.StampGuard` against the last published instant).
  A forged or stale acknowledgement far ahead would otherwise stop the graph or let it run
  ahead of a participant.
- A participant gone from the graph (no publisher of its name on ``sim_sync``) for
  ``gone_after_s`` wall seconds is suspended: the graph goes on without it. It is re-admitted
  when its publisher is back; from then on its acknowledgement of the current instant is awaited
  again (machine_sim re-sends the instant). A participant that is present but silent is the
  lock-step deadline's case (``lockstep_deadline_s``, ``on_late``): a model in a probing cycle is
  alive and must not be skipped.

Wall times are passed in (``wall_s``): the rules are tested on a simulated wall clock.
"""
from __future__ import annotations

import math
from typing import Iterable

from thermal_comp_common.stamp_guard import StampCheck, StampGuard

#: an acknowledgement may equal the published instant up to this rounding (stamps are ns), s
ACK_TOLERANCE_S = 1e-6


class LockstepRoster:
    """The participants of one machine_sim, their acknowledgements and who is suspended."""

    def __init__(self, participants: Iterable[str], gone_after_s: float, stream: str = "sim_sync"):
        if not (math.isfinite(gone_after_s) and gone_after_s > 0):
            raise ValueError(f"participant_gone_s: {gone_after_s!r} must be a finite number > 0")
        self.participants = [n for n in participants if n]
        self.gone_after_s = float(gone_after_s)
        self.acks: dict[str, float] = {}
        self.suspended: set[str] = set()
        self._missing_since: dict[str, float] = {}
        # acknowledgements of several participants interleave: not a forward-only stream
        self.ack_guard = StampGuard(stream, ACK_TOLERANCE_S, forward_only=False)

    @property
    def active(self) -> list[str]:
        """The participants the graph waits for now."""
        return [n for n in self.participants if n not in self.suspended]

    def ack(self, name: str, t_s: float, published_t: float) -> StampCheck | None:
        """Record ``name``'s acknowledgement of ``t_s``; None when ``name`` is no participant.

        Refused (the verdict says why) when ``t_s`` is not finite or ahead of ``published_t``,
        the last instant the graph published."""
        if name not in self.participants:
            return None
        check = self.ack_guard.check(t_s, published_t if math.isfinite(published_t) else None)
        if check.accepted:
            self.acks[name] = max(t_s, self.acks.get(name, -math.inf))
        return check

    def all_acked(self, t_s: float) -> bool:
        """Every active participant has processed instant ``t_s``."""
        return not self.unacked(t_s)

    def unacked(self, t_s: float) -> list[str]:
        return [n for n in self.active if self.acks.get(n, -math.inf) < t_s - ACK_TOLERANCE_S]

    def observe(self, on_graph: set[str], wall_s: float) -> tuple[list[str], list[str]]:
        """Update presence from the publishers of ``sim_sync`` on the graph at ``wall_s``.

        Returns (participants suspended now, participants re-admitted now)."""
        gone: list[str] = []
        back: list[str] = []
        for n in self.participants:
            if n in on_graph:
                self._missing_since.pop(n, None)
                if n in self.suspended:
                    self.suspended.discard(n)
                    back.append(n)
            elif n not in self.suspended:
                since = self._missing_since.setdefault(n, wall_s)
                if wall_s - since >= self.gone_after_s:
                    self.suspended.add(n)
                    gone.append(n)
        return gone, back

    def missing_for(self, name: str, wall_s: float) -> float:
        """Wall seconds ``name`` has been missing from the graph (0 when present)."""
        since = self._missing_since.get(name)
        return 0.0 if since is None else wall_s - since

    def drop(self, names: Iterable[str]) -> None:
        """Remove participants for good (``on_late = drop``)."""
        names = set(names)
        self.participants = [n for n in self.participants if n not in names]
        self.suspended -= names
        for n in names:
            self._missing_since.pop(n, None)
