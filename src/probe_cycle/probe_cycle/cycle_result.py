"""What a probing cycle produces: measured errors with uncertainties, or a failure that says why.

A failed cycle carries no errors at all, so nothing can be published as measured.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

UNIT_UM = "um"
UNIT_UM_PER_M = "um/m"


@dataclass(frozen=True)
class CycleLimits:
    """Acceptance limits of a cycle. A cycle outside any limit fails."""

    max_fit_residual_rms_um: float = 2.0   # RMS residual of one centre fit / skip spread
    max_repeat_distance_um: float = 4.0    # 360 deg vs 0 deg centre distance
    point_sigma_um: float = 0.58           # a-priori standard uncertainty of one trigger


@dataclass(frozen=True)
class MeasuredErrors:
    component_names: tuple[str, ...]
    values: tuple[float, ...]
    units: tuple[str, ...]                 # UNIT_UM or UNIT_UM_PER_M
    uncertainties: tuple[float, ...]       # standard uncertainty, k = 1

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.component_names, self.values))

    def uncertainty_dict(self) -> dict[str, float]:
        return dict(zip(self.component_names, self.uncertainties))


@dataclass(frozen=True)
class CycleResult:
    success: bool
    message: str
    errors: MeasuredErrors | None = None   # None whenever success is False
    stamp_s: float = math.nan              # instant the errors refer to (mid-cycle)
    duration_s: float = 0.0                # time the cycle took, incl. tool changes
    fit_residual_rms_um: float = math.nan
    repeatability_check_um: float = math.nan
    is_reference: bool = False             # this cycle became the reference (zero)
    points_done: int = 0
    details: dict = field(default_factory=dict)


def failure(message: str, **kw) -> CycleResult:
    kw.pop("errors", None)
    return CycleResult(success=False, message=message, errors=None, **kw)
