"""Temperature readings a model refuses whatever their status says (ROS-free).

A publisher may flag any value OK: a forged or broken one sends NaN, inf or 1e9 degC with status
OK. A reading flagged OK whose value is not finite or outside
:data:`thermal_comp_common.sensor_readings.PLAUSIBLE_RANGE_DEGC` is invalid: the model treats it
like a failed sensor (excluded, its contribution held), counts it per kind, and the caller logs
the first message of a burst (messages with invalid readings until ``quiet`` clean ones in a
row) in one line naming the sensors, the values and the instant. Readings the publisher already
flagged not OK are its own, reported by it: passed on as they are.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from thermal_comp_common.sensor_readings import PLAUSIBLE_RANGE_DEGC, STATUS_FAILED, STATUS_OK


@dataclass(frozen=True)
class ReadingVerdict:
    """The check of one message."""

    status: list[int]            # the statuses to model with: invalid readings set to FAILED
    invalid: list[str]           # the sensor ids refused in this message
    log: bool = False            # the first message of a burst: the caller says ``text`` once
    burst_over: bool = False     # this clean message ended a burst
    text: str = ""


class ReadingCheck:
    """Counts and bursts of invalid readings on one ``temperatures`` stream."""

    def __init__(self, range_degc: tuple[float, float] = PLAUSIBLE_RANGE_DEGC, quiet: int = 10):
        lo, hi = (float(v) for v in range_degc)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"range_degc: {range_degc!r} must be finite (low, high) with low < high")
        if quiet < 1:
            raise ValueError(f"quiet: {quiet!r} must be >= 1")
        self.range_degc = (lo, hi)
        self.quiet = int(quiet)
        self.counts = {"non_finite": 0, "out_of_range": 0}
        self.last_refusal = ""
        self.in_burst = False
        self._clean_in_row = 0

    @property
    def refused(self) -> int:
        return sum(self.counts.values())

    def check(self, t_s: float, sensor_ids: Sequence[str], values: Sequence[float],
              status: Sequence[int]) -> ReadingVerdict:
        """Check the readings of instant ``t_s`` (parallel sequences of equal length)."""
        lo, hi = self.range_degc
        out = [int(s) for s in status]
        bad: list[str] = []
        ids: list[str] = []
        for i, (sid, v, st) in enumerate(zip(sensor_ids, values, status)):
            if int(st) != STATUS_OK:
                continue
            v = float(v)
            if not math.isfinite(v):
                self.counts["non_finite"] += 1
            elif not lo <= v <= hi:
                self.counts["out_of_range"] += 1
            else:
                continue
            out[i] = STATUS_FAILED
            ids.append(str(sid))
            bad.append(f"{sid}={v!r}")
        if not bad:
            self._clean_in_row += 1
            over = self.in_burst and self._clean_in_row >= self.quiet
            if over:
                self.in_burst = False
            return ReadingVerdict(out, [], burst_over=over)
        self._clean_in_row = 0
        text = (f"temperatures at {t_s:.3f} s: {len(bad)} reading(s) flagged OK refused, not finite or outside "
                f"[{lo:g}, {hi:g}] degC: {', '.join(bad[:8])}{' ...' if len(bad) > 8 else ''} "
                f"(excluded like a failed sensor; {self.refused} refused so far, further ones of this burst "
                "are counted, not logged)")
        self.last_refusal = text
        first = not self.in_burst
        self.in_burst = True
        return ReadingVerdict(out, ids, log=first, text=text)

    def values(self) -> dict[str, object]:
        """The ``/diagnostics`` values: refusals per kind, the range, the newest refusal."""
        return {"readings_refused_non_finite": self.counts["non_finite"],
                "readings_refused_out_of_range": self.counts["out_of_range"],
                "plausible_range_degc": f"{self.range_degc[0]:g}..{self.range_degc[1]:g}",
                "last_reading_refused": self.last_refusal or "none"}
