"""Honest per-sensor status: ok, stale, out of range, failed.

Rules, in order of precedence (the first that applies wins):

1. FAILED: the read failed (error, timeout, fault code), the value is NaN/inf, or the
   newest reading is older than ``max_age_s`` (the source produced nothing new: an old
   value is never repeated as ok). The published value is NaN.
2. OUT_OF_RANGE: the corrected value (gain/offset applied) lies outside the sensor's measuring range.
3. STALE: the value has not changed by more than ``stale_tolerance_degc`` for longer
   than ``stale_after_s`` (a stuck transmitter or a frozen gateway). 0 disables the rule;
   set it well above the longest plateau a healthy (quantised) sensor shows.
4. OK.

The codes equal the ``STATUS_*`` constants of ``thermal_comp_msgs/TemperatureArray``.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class SensorStatus(enum.IntEnum):
    OK = 0
    STALE = 1
    OUT_OF_RANGE = 2
    FAILED = 3


@dataclass(frozen=True)
class StatusRule:
    range_lo_degc: float
    range_hi_degc: float
    stale_after_s: float = 0.0
    stale_tolerance_degc: float = 0.0
    max_age_s: float = math.inf


class SensorStatusTracker:
    """Status of one sensor over a stream of readings (state: when it last changed)."""

    def __init__(self, rule: StatusRule):
        self.rule = rule
        self._ref_value: float | None = None   # value at the last change
        self._ref_t: float = -math.inf         # time of the last change
        self.last_reason = ""

    def reset(self) -> None:
        self._ref_value = None
        self._ref_t = -math.inf

    def update(self, t_s: float, value_degc: float, read_ok: bool = True,
               acquired_t_s: float | None = None, reason: str = "") -> tuple[float, SensorStatus]:
        """Status of the reading ``value_degc`` published at ``t_s``.

        ``acquired_t_s`` is when the value was read (defaults to ``t_s``); ``reason``
        explains a failed read. Returns (value to publish, status).
        """
        r = self.rule
        if self._ref_value is not None and t_s < self._ref_t:
            self.reset()  # time went backwards (a replay restarted): forget the history
        acquired = t_s if acquired_t_s is None else acquired_t_s
        if not read_ok:
            self.last_reason = reason or "read failed"
            return math.nan, SensorStatus.FAILED
        if not math.isfinite(value_degc):
            self.last_reason = reason or "value is not a number"
            return math.nan, SensorStatus.FAILED
        age = t_s - acquired
        if age > r.max_age_s:
            self.last_reason = f"newest reading is {age:.3g} s old (max_age_s {r.max_age_s:g})"
            return math.nan, SensorStatus.FAILED
        if self._ref_value is None or abs(value_degc - self._ref_value) > r.stale_tolerance_degc:
            self._ref_value = value_degc
            self._ref_t = t_s
        if not r.range_lo_degc <= value_degc <= r.range_hi_degc:
            self.last_reason = (f"{value_degc:g} degC outside the range "
                                f"[{r.range_lo_degc:g}, {r.range_hi_degc:g}]")
            return value_degc, SensorStatus.OUT_OF_RANGE
        if r.stale_after_s > 0 and t_s - self._ref_t > r.stale_after_s:
            self.last_reason = f"unchanged for {t_s - self._ref_t:.6g} s (stale_after_s {r.stale_after_s:g})"
            return value_degc, SensorStatus.STALE
        self.last_reason = ""
        return value_degc, SensorStatus.OK
