"""Whether a learned unit twin replaces the type's: decided on probes the fit did not see
(the validation probes between the end of the fit window and the decision time), never on
later ones. The unit twin is adopted when, open loop on those probes, its noise-normalised sum
of squared errors is lower than the type twin's AND no component is worse by more than that
component's probe uncertainty; its prior then must pass the same test with the adaptive model
(each probe predicted before it is seen) by a margin: ADAPTIVE_MARGIN of the normalised SSE of
the prior it would replace (the type's, or with ``--current-prior`` the one running now), since a
few validation probes decide what runs for days (a hall-sensor-bias unit passed at 0.89 x and was
worse over the rest of its run). Otherwise the twin and prior in use stay. No rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from thermal_comp_common import metrics

#: fewest validation probes (instants) a decision needs
MIN_VALIDATION_PROBES = 3
#: the unit prior's adaptive model must reach this fraction of the type prior's normalised SSE
ADAPTIVE_MARGIN = 0.8


@dataclass
class Adoption:
    adopt: bool
    reason: str
    rmse: dict[str, dict[str, float]] = field(default_factory=dict)   # component -> {type, unit}
    probes: int = 0

    def as_dict(self) -> dict:
        return {"adopt": self.adopt, "reason": self.reason, "validation_probes": self.probes,
                "validation_rmse": self.rmse}


def decide(values: dict[str, np.ndarray], noise: dict[str, float], type_pred: dict[str, np.ndarray],
           unit_pred: dict[str, np.ndarray], mask: np.ndarray, margin: float = 1.0) -> Adoption:
    """The decision on the probes of ``mask`` (module docstring); ``margin``: the unit's
    normalised SSE must be below this fraction of the type's."""
    n = int(mask.sum())
    if n < MIN_VALIDATION_PROBES:
        return Adoption(False, f"only {n} validation probes (need {MIN_VALIDATION_PROBES}): the twin in use stays",
                        probes=n)
    rmse, cost_t, cost_u, worse = {}, 0.0, 0.0, []
    for c, v in values.items():
        ok = mask & np.isfinite(v)
        rt, ru = metrics.rmse(v[ok], type_pred[c][ok]), metrics.rmse(v[ok], unit_pred[c][ok])
        rmse[c] = {"type": rt, "unit": ru}
        if not (math.isfinite(rt) and math.isfinite(ru)):
            continue
        cost_t += (rt / noise[c]) ** 2
        cost_u += (ru / noise[c]) ** 2
        if ru > rt + noise[c]:
            worse.append(f"{c} {rt:.2f} -> {ru:.2f}")
    if worse:
        return Adoption(False, "worse beyond the probe uncertainty on " + ", ".join(worse), rmse, n)
    if not cost_u < margin * cost_t:
        return Adoption(False, f"not better by the margin on the validation probes (normalised SSE {cost_u:.1f} "
                               f"vs {cost_t:.1f}; needs below {margin:g} x)", rmse, n)
    return Adoption(True, f"better on {n} validation probes (normalised SSE {cost_u:.1f} vs {cost_t:.1f}), "
                          "no component worse beyond its probe uncertainty", rmse, n)
