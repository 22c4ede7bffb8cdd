"""Evaluation of a guide-bush cycle (torque-limit skip in X on a Swiss-type lathe).

The value is the mean X skip position of the repeats minus the mean of the reference
(zero) cycle, in um. The first cycle of a tool position becomes its zero (AGP thesis §1).
A positive value means the contact moved to +X. The skips fall on discrete levels and
scatter within +-0.5 um, so:

* the spread check fails the cycle when the RMS deviation of the repeats from their mean
  exceeds the residual limit (a slipping or fouled probe block);
* the standard uncertainty of a mean of n skips is ``sigma_point / sqrt(n)``, with
  ``sigma_point`` from the probe model (scatter and level spacing). The reference's
  uncertainty is added in quadrature.
"""
from __future__ import annotations

import math

import numpy as np

from probe_cycle.cycle_plan import CyclePlan
from probe_cycle.cycle_reference import GuideBushReference
from probe_cycle.cycle_result import UNIT_UM, CycleLimits, CycleResult, MeasuredErrors, failure
from probe_cycle.probe_backend import TouchReply

UM_PER_MM = 1000.0


def evaluate_guide_bush_cycle(plan: CyclePlan, replies: list[TouchReply],
                              limits: CycleLimits, point_sigma_um: float,
                              reference: GuideBushReference | None, make_reference: bool,
                              component: str) -> tuple[CycleResult, GuideBushReference | None]:
    stamps = [r.stamp_s for r in replies]
    stamp = float(0.5 * (min(stamps) + max(stamps))) if stamps else float("nan")
    common = dict(duration_s=plan.duration_s, stamp_s=stamp, points_done=len(replies))
    if len(replies) != len(plan.moves):
        return failure(f"incomplete cycle: {len(replies)} of {len(plan.moves)} skips "
                       f"measured", **common), None
    for move, reply in zip(plan.moves, replies):
        if not reply.triggered:
            return failure(f"missing trigger (no torque-limit skip) at {move.stage}",
                           **common), None
    x_um = np.array([r.position_mm[0] for r in replies]) * UM_PER_MM
    mean = float(x_um.mean())
    spread = float(np.sqrt(np.mean((x_um - mean) ** 2)))
    common["fit_residual_rms_um"] = spread
    if spread > limits.max_fit_residual_rms_um:
        return failure(f"guide-bush skips scatter by {spread:.2f} um RMS, above the limit "
                       f"{limits.max_fit_residual_rms_um:g} um", **common), None
    u_mean = point_sigma_um / math.sqrt(len(x_um))
    new_ref = None
    if make_reference or reference is None:
        new_ref = GuideBushReference(mean, u_mean, stamp)
        value, u = 0.0, u_mean
        why = "requested" if make_reference else "first cycle"
        msg = f"zero reference of {component} taken ({why})"
    else:
        value = mean - reference.position_um
        u = math.hypot(u_mean, reference.uncertainty_um)
        msg = f"{component}={value:+.2f} um relative to the zero reference"
    errors = MeasuredErrors((component,), (value,), (UNIT_UM,), (u,))
    return CycleResult(success=True, message=f"{msg}; skip spread {spread:.2f} um RMS",
                       errors=errors, is_reference=new_ref is not None, **common), new_ref
