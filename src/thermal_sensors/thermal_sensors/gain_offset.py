"""Per-sensor gain/offset correction: corrected = gain * raw + offset (degC).

An RTD channel's error is dominated by an offset (lead resistance, reference) and a gain
(alpha of the element, module span); both come from comparing against a reference
thermometer at two temperatures (:meth:`GainOffset.from_two_points`: a two-point sensor
calibration, the ``calibration:`` key of the sensor YAML). Unrelated to fitting the twin
(:mod:`thermal_twin.calibrate`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GainOffset:
    offset_degc: float = 0.0
    gain: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.offset_degc) and math.isfinite(self.gain)) or self.gain == 0:
            raise ValueError(f"sensor gain/offset: offset_degc={self.offset_degc!r}, gain={self.gain!r}: "
                             "need finite values and a non-zero gain")

    def apply(self, raw_degc):
        """Corrected value(s); NaN stays NaN."""
        return self.gain * np.asarray(raw_degc, dtype=float) + self.offset_degc

    def invert(self, corrected_degc):
        """The raw reading that corrects to ``corrected_degc``."""
        return (np.asarray(corrected_degc, dtype=float) - self.offset_degc) / self.gain

    @classmethod
    def from_two_points(cls, raw_1: float, ref_1: float, raw_2: float, ref_2: float) -> "GainOffset":
        """The correction mapping two raw readings onto their reference temperatures."""
        if raw_1 == raw_2:
            raise ValueError(f"sensor gain/offset: the two raw readings are equal ({raw_1!r}); "
                             "need two different temperatures")
        gain = (ref_2 - ref_1) / (raw_2 - raw_1)
        return cls(offset_degc=ref_1 - gain * raw_1, gain=gain)
