"""The machine state of an instant before its temperatures are modelled (lock-step graphs).

machine_sim publishes the machine state and the sensor readings of instant t_k together; the
temperatures reach the model one hop later. A subscription that matched late (at start-up) can
still leave the model without the state of t_k when its temperatures arrive, and modelling them
then feeds the soft sensors the previous instant's inputs, or none: the run would depend on
DDS timing. So a lock-step model keeps the temperatures of t_k aside, neither modelling nor
acknowledging them, until the state of t_k arrives (later, or with machine_sim's re-send of the
instant). The wait is bounded (``max_wait_s`` wall seconds, checked on the caller's timer too);
after it the instant is modelled with the last inputs, which the caller says once.
"""
from __future__ import annotations

import enum
import math


class InputsReady(enum.Enum):
    STEP = "step"              # the state of the instant is here
    WAIT = "wait"              # not yet: neither model nor acknowledge the instant
    STEP_HELD = "step_held"    # waited max_wait_s: model it with the last inputs


class InstantInputs:
    """Tracks the newest machine-state stamp and decides whether an instant may be modelled."""

    def __init__(self, max_wait_s: float) -> None:
        if not (max_wait_s >= 0.0 and math.isfinite(max_wait_s)):
            raise ValueError(f"max_wait_s: {max_wait_s!r} must be a finite number >= 0")
        self.max_wait_s = float(max_wait_s)
        self.state_t = -math.inf
        self._waiting_t: float | None = None
        self._since_wall_s = 0.0

    def state_arrived(self, t_s: float) -> None:
        """A machine state stamped ``t_s`` arrived (non-finite stamps are ignored)."""
        if math.isfinite(t_s):
            self.state_t = max(self.state_t, t_s)

    def ready(self, t_s: float, wall_s: float) -> InputsReady:
        """May the temperatures of instant ``t_s`` be modelled now (``wall_s``: wall clock, s)?"""
        if self.state_t >= t_s - 1e-6:
            self._waiting_t = None
            return InputsReady.STEP
        if self._waiting_t != t_s:
            self._waiting_t, self._since_wall_s = t_s, wall_s
        if wall_s - self._since_wall_s < self.max_wait_s:
            return InputsReady.WAIT
        self._waiting_t = None
        return InputsReady.STEP_HELD
