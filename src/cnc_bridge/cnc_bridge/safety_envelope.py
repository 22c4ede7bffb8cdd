"""Safety envelope between a model's commanded offsets and what may reach the CNC (pure core).

Per axis, in this order:
1. **enable**: disabled -> the target is 0, approached at ``disable_ramp_um_per_s``
   (flag LIMIT_DISABLED); re-enabling ramps up again under the normal rate limit.
2. **watchdog**: no fresh prediction for ``watchdog_timeout_s`` (of the steps' time, or of
   the caller's ``silent_s``: how long since one arrived) -> hold the applied value
   for ``watchdog_hold_s``, then ramp to zero at ``watchdog_ramp_um_per_s`` (0 = hold
   forever) (flag LIMIT_WATCHDOG). Before the first prediction the target is 0 and the
   watchdog flag is set, because nothing fresh has ever arrived.
3. **absolute limit**: the target is clamped to +-``abs_limit_um`` (per-axis overrides in
   ``axis_abs_limits_um``) (flag LIMIT_ABSOLUTE).
4. **rate limit**: the applied value moves towards the target by at most
   ``max_rate_um_per_s * dt`` (flag LIMIT_RATE), like SINUMERIK MD32760 limits the
   compensation change per interpolation cycle. ``dt`` is capped at ``max_step_s`` so
   that a long pause (an outage, a stalled clock) never licenses a jump.

The envelope's "applied" state is what the CNC confirmed by read-back (:meth:`confirm`);
a write that fails leaves it at the last confirmed value (the caller reports
LIMIT_WRITE_FAILED for that write). At start-up (:meth:`SafetyEnvelope.adopt_held`) an offset
the CNC applies beyond the absolute limit is never clamped (that would be one write of the
whole difference): it is marked refused, and the bridge does not activate against it.
The flag values are those of thermal_comp_msgs/AxisOffsets.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

# Bit flags, identical to thermal_comp_msgs/msg/AxisOffsets.msg LIMIT_* (checked in a test).
LIMIT_NONE = 0
LIMIT_ABSOLUTE = 1
LIMIT_RATE = 2
LIMIT_WATCHDOG = 4
LIMIT_DISABLED = 8
LIMIT_WRITE_FAILED = 16

FLAG_NAMES = {LIMIT_ABSOLUTE: "absolute", LIMIT_RATE: "rate", LIMIT_WATCHDOG: "watchdog",
              LIMIT_DISABLED: "disabled", LIMIT_WRITE_FAILED: "write_failed"}


def flag_names(flags: int) -> str:
    """``3`` -> ``"absolute|rate"``; ``0`` -> ``"none"``."""
    names = [n for bit, n in FLAG_NAMES.items() if flags & bit]
    return "|".join(names) if names else "none"


class EnvelopeConfigError(ValueError):
    """A safety-envelope setting is out of range (the message names it)."""


@dataclass(frozen=True)
class EnvelopeConfig:
    """Limits of the safety envelope; defaults are conservative (off-by-default spirit)."""

    abs_limit_um: float = 30.0
    axis_abs_limits_um: Mapping[str, float] = field(default_factory=dict)
    max_rate_um_per_s: float = 0.5
    max_step_s: float = 10.0
    watchdog_timeout_s: float = 900.0       # 3 prediction periods of 5 min
    watchdog_hold_s: float = 300.0
    watchdog_ramp_um_per_s: float = 0.05
    disable_ramp_um_per_s: float = 0.5

    def __post_init__(self):
        def positive(name, v, allow_zero=False):
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 \
                    or (v == 0 and not allow_zero):
                raise EnvelopeConfigError(
                    f"safety envelope: '{name}' must be a finite number "
                    f"{'>= 0' if allow_zero else '> 0'}, got {v!r}")
        positive("abs_limit_um", self.abs_limit_um, allow_zero=True)
        for axis, v in self.axis_abs_limits_um.items():
            positive(f"axis_abs_limits_um.{axis}", v, allow_zero=True)
        positive("max_rate_um_per_s", self.max_rate_um_per_s)
        positive("max_step_s", self.max_step_s)
        positive("watchdog_timeout_s", self.watchdog_timeout_s)
        positive("watchdog_hold_s", self.watchdog_hold_s, allow_zero=True)
        positive("watchdog_ramp_um_per_s", self.watchdog_ramp_um_per_s, allow_zero=True)
        positive("disable_ramp_um_per_s", self.disable_ramp_um_per_s)

    def limit_for(self, axis: str) -> float:
        return float(self.axis_abs_limits_um.get(axis, self.abs_limit_um))


@dataclass(frozen=True)
class AxisDecision:
    """One axis after one envelope step: what was asked, what to write, and why it differs."""

    axis: str
    commanded_um: float      # the model's command (NaN before the first prediction)
    target_um: float         # after enable / watchdog / clamp
    applied_um: float        # rate-limited value to write to the CNC
    flags: int               # LIMIT_* bits


@dataclass(frozen=True)
class HeldAdoption:
    """What the CNC held on one axis at start-up and what the envelope adopted from it."""

    axis: str
    held_um: float           # the raw value the CNC holds
    compensation_on: bool    # the CNC applied it (False: it held the value with compensation off)
    adopted_um: float        # what counts as applied now (0 when compensation was off)
    flags: int               # LIMIT_ABSOLUTE (beyond the limit / not finite), LIMIT_DISABLED (was off)
    refused: str = ""        # why activation must be refused ("": the held value is within the envelope)

    def describe(self) -> str:
        state = "on" if self.compensation_on else "off"
        if self.refused:
            return (f"{self.axis}: held {self.held_um:.3f} um (compensation {state}), "
                    f"{self.refused} [{flag_names(self.flags)}]")
        return (f"{self.axis}: held {self.held_um:.3f} um (compensation {state}), adopted "
                f"{self.adopted_um:.3f} um [{flag_names(self.flags)}]")


class SafetyEnvelope:
    """Stateful per-axis envelope; drive it with :meth:`step`, feed read-back with :meth:`confirm`."""

    def __init__(self, config: EnvelopeConfig | None = None, enabled: bool = True):
        self.config = config or EnvelopeConfig()
        self.enabled = bool(enabled)
        self._commanded: dict[str, float] = {}
        self._applied: dict[str, float] = {}
        self._last_t: float | None = None
        self._last_fresh_t: float | None = None
        self._watchdog_since: float | None = None

    @property
    def applied(self) -> dict[str, float]:
        """Last values the CNC confirmed, per axis (um)."""
        return dict(self._applied)

    @property
    def last_fresh_t(self) -> float | None:
        return self._last_fresh_t

    def set_enabled(self, enabled: bool) -> None:
        self.enabled = bool(enabled)

    def reconfigure(self, config: EnvelopeConfig) -> None:
        """Apply new limits from the next step on (a runtime parameter change). The config
        validated itself on construction; the applied offsets stay, and the next step moves
        them into the new envelope under the (new) rate limit."""
        if not isinstance(config, EnvelopeConfig):
            raise TypeError(f"expected an EnvelopeConfig, got {type(config).__name__}")
        self.config = config

    def adopt_held(self, held_um: Mapping[str, float],
                   compensation_on: Mapping[str, bool] | None = None) -> list[HeldAdoption]:
        """Start from offsets the CNC already holds (a restarted bridge or CNC).

        An axis whose compensation was switched off on the CNC (``compensation_on[axis]``
        False) holds nothing in effect: it counts as 0 and the ramp starts from 0 (switching
        compensation on with the raw value would move the machine by it in one step). A
        value applied beyond the axis' absolute limit, or not finite, is not brought into
        the envelope here: clamping it would be one step of the whole difference. It is
        marked ``refused`` (the bridge must not activate) and counts as applied as it is
        (a non-finite one as 0), so that even a caller that writes anyway moves from it at
        the rate limit, never by a jump. The adopted values count as applied and
        commanded. Returns one :class:`HeldAdoption` per axis for the audit.
        """
        out = []
        for a, v in sorted(held_um.items()):
            raw = float(v)
            on = True if compensation_on is None else bool(compensation_on.get(a, True))
            flags, value, refused = LIMIT_NONE, raw, ""
            limit = self.config.limit_for(a)
            if not on:     # flagged only when something was held: that value is dropped
                value, flags = 0.0, (LIMIT_DISABLED if raw != 0.0 else LIMIT_NONE)
            elif not math.isfinite(raw):
                value, flags = 0.0, LIMIT_ABSOLUTE
                refused = "not a finite offset: what the axis applies is unknown"
            elif abs(raw) > limit:
                flags = LIMIT_ABSOLUTE
                refused = (f"beyond the absolute limit {limit:g} um: the first write would move "
                           f"the axis by {abs(raw) - limit:.3f} um at once")
            self._applied[a] = value
            self._commanded[a] = value
            out.append(HeldAdoption(a, raw, on, value, flags, refused))
        return out

    def add_axes(self, axes) -> None:
        for a in axes:
            self._applied.setdefault(a, 0.0)

    def step(self, t_s: float, commanded_um: Mapping[str, float] | None = None,
             fresh: bool = False, silent_s: float | None = None) -> list[AxisDecision]:
        """Advance to time ``t_s`` [s]; ``commanded_um`` replaces the command of those axes.

        ``fresh`` marks ``commanded_um`` as a new prediction (it resets the watchdog); a
        command recomputed from an old prediction at new axis positions is not fresh.
        ``silent_s``: how long no fresh prediction has arrived, on the caller's clock (the
        bridge: wall seconds); beyond the timeout the watchdog holds whatever the stamps say.
        Non-finite commands raise :class:`ValueError` naming the axis; nothing changes then.
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"envelope time must be finite, got {t_s!r}")
        if commanded_um:
            for axis, v in commanded_um.items():
                if not math.isfinite(float(v)):
                    raise ValueError(f"commanded offset for axis '{axis}' is not finite: {v!r}")
            for axis, v in commanded_um.items():
                self._commanded[axis] = float(v)
                self._applied.setdefault(axis, 0.0)
        if fresh:
            self._last_fresh_t = t
        dt = 0.0 if self._last_t is None else min(max(t - self._last_t, 0.0), self.config.max_step_s)
        self._last_t = t if self._last_t is None else max(self._last_t, t)

        cfg = self.config
        age = math.inf if self._last_fresh_t is None else t - self._last_fresh_t
        stamps_late = age > cfg.watchdog_timeout_s
        watchdog = stamps_late or self._last_fresh_t is None or \
            (silent_s is not None and silent_s > cfg.watchdog_timeout_s)
        if watchdog and self._watchdog_since is None:
            self._watchdog_since = self._last_fresh_t + cfg.watchdog_timeout_s \
                if self._last_fresh_t is not None and stamps_late else t
        elif not watchdog:
            self._watchdog_since = None
        ramp_to_zero = watchdog and (self._last_fresh_t is None or (
            cfg.watchdog_ramp_um_per_s > 0 and t - self._watchdog_since > cfg.watchdog_hold_s))

        out = []
        for axis in sorted(self._applied):
            prev = self._applied[axis]
            commanded = self._commanded.get(axis, math.nan)
            flags = LIMIT_NONE
            limit = cfg.limit_for(axis)
            if not self.enabled:
                target, rate = 0.0, cfg.disable_ramp_um_per_s
                flags |= LIMIT_DISABLED
            elif watchdog:
                flags |= LIMIT_WATCHDOG
                if ramp_to_zero:
                    target = 0.0
                    rate = (cfg.watchdog_ramp_um_per_s if self._last_fresh_t is not None
                            else cfg.max_rate_um_per_s)
                else:
                    target, rate = prev, cfg.max_rate_um_per_s
            else:
                target, rate = commanded, cfg.max_rate_um_per_s
            if abs(target) > limit:
                target = math.copysign(limit, target)
                flags |= LIMIT_ABSOLUTE
            allow = rate * dt
            delta = target - prev
            if abs(delta) > allow:
                applied = prev + math.copysign(allow, delta)
                if flags & (LIMIT_DISABLED | LIMIT_WATCHDOG) == 0:
                    flags |= LIMIT_RATE
            else:
                applied = target
            out.append(AxisDecision(axis, commanded, target, applied, flags))
        return out

    def confirm(self, axis: str, applied_um: float | None) -> None:
        """Record the CNC's read-back for ``axis``; ``None`` = the write was not confirmed."""
        if applied_um is None or not math.isfinite(applied_um):
            return      # keep the last confirmed value: the CNC may still hold it
        self._applied[axis] = float(applied_um)
