"""Evaluation of a sphere cycle: centre fits, checks, the seven errors with uncertainties.

Input: the plan and one reply per move (all triggered; the runner stops at a missing
trigger). Steps:

1. Fit the sphere centre at every C indexing (known radius = sphere + stylus tip).
2. Fail if any fit's RMS residual exceeds the limit.
3. Map the indexings to k = 1..4 (C = 0, 90, 180, 270). Every further indexing at one of
   these angles (360 = 0) is a repeatability check: the distance between its centre and
   the first centre at that angle must stay within the tolerance.
4. Compute the errors relative to the reference by eq. 5.4-5.10, or make this cycle the
   reference (errors zero by definition) when asked to or when there is none yet.
"""
from __future__ import annotations

import numpy as np

from thermal_twin.machine.artefact_geometry import ANGULAR_COMPONENTS, SPHERE_COMPONENTS

from probe_cycle.cycle_plan import CyclePlan
from probe_cycle.cycle_reference import SphereReference
from probe_cycle.cycle_result import (UNIT_UM, UNIT_UM_PER_M, CycleLimits, CycleResult,
                                      MeasuredErrors, failure)
from probe_cycle.location_equations import EQUATION_C_ANGLES_DEG, location_errors
from probe_cycle.probe_backend import TouchReply
from probe_cycle.sphere_fit import SphereFit, SphereFitError, fit_sphere_centre

UM_PER_MM = 1000.0


def _angle_slot(angle_deg: float) -> int | None:
    """k - 1 for C angles equal (mod 360) to 0, 90, 180, 270; else None."""
    a = angle_deg % 360.0
    for k, ref in enumerate(EQUATION_C_ANGLES_DEG):
        if min(abs(a - ref), 360.0 - abs(a - ref)) < 1e-6:
            return k
    return None


def _fit_centres(plan: CyclePlan, replies: list[TouchReply], limits: CycleLimits,
                 common: dict) -> tuple[list[SphereFit], CycleResult | None]:
    """One sphere fit per C indexing, or the failure of the first that fails or fits badly."""
    fits = []
    for g, angle in enumerate(plan.c_angles_deg):
        idx = [i for i, m in enumerate(plan.moves) if m.group == g]
        pts = np.array([replies[i].position_mm for i in idx])
        dirs = np.array([plan.moves[i].direction for i in idx])
        try:
            fit = fit_sphere_centre(pts, dirs, plan.contact_radius_mm, limits.point_sigma_um,
                                    np.asarray(plan.nominal_centres_mm[g]))
        except SphereFitError as exc:
            return fits, failure(f"sphere fit at C={angle:g} failed: {exc}", **common)
        if fit.rms_residual_um > limits.max_fit_residual_rms_um:
            return fits, failure(f"sphere fit at C={angle:g}: RMS residual "
                                 f"{fit.rms_residual_um:.2f} um exceeds the limit "
                                 f"{limits.max_fit_residual_rms_um:g} um",
                                 fit_residual_rms_um=fit.rms_residual_um, **common)
        fits.append(fit)
    return fits, None


def _check_repeats(plan: CyclePlan, fits: list[SphereFit], limits: CycleLimits, common: dict
                   ) -> tuple[dict[int, int], float, CycleResult | None]:
    """(equation slot k -> first indexing at that angle, largest repeat distance in um or NaN,
    the failure if a repeated angle's centre moved more than the tolerance)."""
    first: dict[int, int] = {}
    repeat = float("nan")
    for g, angle in enumerate(plan.c_angles_deg):
        k = _angle_slot(angle)
        if k is None:
            continue
        if k not in first:
            first[k] = g
            continue
        dist = float(np.linalg.norm(fits[g].centre_mm - fits[first[k]].centre_mm)) * UM_PER_MM
        repeat = dist if not np.isfinite(repeat) else max(repeat, dist)
        if dist > limits.max_repeat_distance_um:
            return first, repeat, failure(
                f"repeatability check failed: the centre at C={angle:g} is {dist:.2f} um "
                f"from the one at C={plan.c_angles_deg[first[k]]:g} (tolerance "
                f"{limits.max_repeat_distance_um:g} um)",
                repeatability_check_um=dist, **common)
    return first, repeat, None


def evaluate_sphere_cycle(plan: CyclePlan, replies: list[TouchReply], limits: CycleLimits,
                          reference: SphereReference | None, make_reference: bool,
                          d_m: float) -> tuple[CycleResult, SphereReference | None]:
    """Result of the cycle and, if it becomes the reference, the new reference."""
    duration = plan.duration_s
    stamps = [r.stamp_s for r in replies]
    stamp = float(0.5 * (min(stamps) + max(stamps))) if stamps else float("nan")
    common = dict(duration_s=duration, stamp_s=stamp, points_done=len(replies))
    if len(replies) != len(plan.moves):
        return failure(f"incomplete cycle: {len(replies)} of {len(plan.moves)} points "
                       f"measured", **common), None
    for move, reply in zip(plan.moves, replies):
        if not reply.triggered:
            return failure(f"missing trigger at {move.stage}", **common), None

    fits, failed = _fit_centres(plan, replies, limits, common)
    if failed is not None:
        return failed, None
    rms = float(np.sqrt(np.mean(np.concatenate([f.residuals_um for f in fits]) ** 2)))
    common["fit_residual_rms_um"] = rms
    first, repeat, failed = _check_repeats(plan, fits, limits, common)
    if failed is not None:
        return failed, None
    common["repeatability_check_um"] = repeat
    missing = [EQUATION_C_ANGLES_DEG[k] for k in range(4) if k not in first]
    if missing:
        return failure("c_angles_deg: eq. 5.4-5.10 need the C indexings 0, 90, 180, 270; "
                       f"missing {', '.join(f'{a:g}' for a in missing)}", **common), None

    centres = np.array([fits[first[k]].centre_mm for k in range(4)]) * UM_PER_MM
    covs = np.array([fits[first[k]].covariance_um2 for k in range(4)])
    new_ref = None
    if make_reference or reference is None:
        new_ref = SphereReference(centres, covs, stamp)
        _, u = location_errors(centres, centres, d_m, covs, None)   # own uncertainty only
        values = np.zeros(7)                                          # zero by definition
        why = "requested" if make_reference else "no reference existed"
        msg = f"reference cycle ({why}); errors are zero by definition"
    else:
        values, u = location_errors(centres, reference.centres_um, d_m, covs,
                                    reference.covariances_um2)
        msg = "measured relative to the reference cycle"
    units = tuple(UNIT_UM_PER_M if c in ANGULAR_COMPONENTS else UNIT_UM
                  for c in SPHERE_COMPONENTS)
    errors = MeasuredErrors(SPHERE_COMPONENTS, tuple(float(v) for v in values), units,
                            tuple(float(x) for x in u))
    summary = ", ".join(f"{c}={v:+.2f}" for c, v in zip(SPHERE_COMPONENTS, values))
    return CycleResult(success=True, message=f"{msg}: {summary}; fit RMS {rms:.2f} um",
                       errors=errors, is_reference=new_ref is not None,
                       details={"centres_mm": [f.centre_mm.tolist() for f in fits]},
                       **common), new_ref
