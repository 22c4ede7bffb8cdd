"""Per-sensor two-point calibration: calibrated = gain * raw + offset (degC).

An RTD channel's error is dominated by an offset (lead resistance, reference) and a gain
(alpha of the element, module span); both are found by comparing against a reference
thermometer at two temperatures (:meth:`Calibration.from_two_points`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Calibration:
    offset_degc: float = 0.0
    gain: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.offset_degc) and math.isfinite(self.gain)) or self.gain == 0:
            raise ValueError(f"calibration: offset_degc={self.offset_degc!r}, gain={self.gain!r}: "
                             "need finite values and a non-zero gain")

    def apply(self, raw_degc):
        """Calibrated value(s); NaN stays NaN."""
        return self.gain * np.asarray(raw_degc, dtype=float) + self.offset_degc

    def invert(self, calibrated_degc):
        """The raw reading that calibrates to ``calibrated_degc``."""
        return (np.asarray(calibrated_degc, dtype=float) - self.offset_degc) / self.gain

    @classmethod
    def from_two_points(cls, raw_1: float, ref_1: float, raw_2: float, ref_2: float) -> "Calibration":
        """Calibration mapping two raw readings onto their reference temperatures."""
        if raw_1 == raw_2:
            raise ValueError(f"calibration: the two raw readings are equal ({raw_1!r}); "
                             "need two different temperatures")
        gain = (ref_2 - ref_1) / (raw_2 - raw_1)
        return cls(offset_degc=ref_1 - gain * raw_1, gain=gain)
