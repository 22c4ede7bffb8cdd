"""Planning of probing cycles: which moves, in what order, and how much time each takes.

Sphere cycle (Blaser 2020, §5.2) and guide-bush cycle (AGP thesis §1.5); every move carries
the simulated time it consumes. The layout of the touches and where the timings come from
(the thesis's 95 s cycle; the split is an assumption): README.md ("Cycle plans").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from thermal_twin.machine.artefact_geometry import (ARTEFACT_GUIDE_BUSH, ARTEFACT_SPHERE,
                                            ArtefactGeometry, nominal_sphere_centre)

DEFAULT_C_ANGLES_DEG = (0.0, 90.0, 180.0, 270.0, 360.0)
DEFAULT_SPHERE_POINTS = 5
MIN_SPHERE_POINTS = 4          # 3 unknowns (centre) + 1 so that a residual exists
DEFAULT_GUIDE_BUSH_REPEATS = 3
RING_POLAR_ANGLE_DEG = 45.0    # ring points: 45 degrees down from the pole


class PlanError(ValueError):
    """A goal asks for a cycle that cannot be planned; the message names the field."""


@dataclass(frozen=True)
class SphereTiming:
    tool_change_s: float = 10.0    # each of the two tool changes (probe in, probe out)
    indexing_s: float = 5.0        # C index move and approach, per indexing
    touch_s: float = 2.0           # positioning + probing move + retract, per point


@dataclass(frozen=True)
class GuideBushTiming:
    approach_s: float = 4.0        # move the TLS probe block to the guide bush and back
    touch_s: float = 3.0           # one G31 P98 skip at low feed, per repeat


@dataclass(frozen=True)
class TouchMove:
    """One probing move, as sent to a probe backend."""

    artefact: int
    c_axis_deg: float
    b_axis_deg: float
    start_mm: tuple[float, float, float]
    direction: tuple[float, float, float]
    max_travel_mm: float
    duration_s: float              # simulated time this move consumes (incl. overhead)
    group: int                     # index of the C indexing (sphere) or 0 (guide bush)
    stage: str                     # human-readable, e.g. "C=90 point 3/5"


@dataclass(frozen=True)
class CyclePlan:
    artefact: int
    moves: tuple[TouchMove, ...]
    c_angles_deg: tuple[float, ...]    # one per group (sphere); empty for the guide bush
    points_per_group: int
    contact_radius_mm: float           # sphere + stylus tip radius (sphere cycles)
    nominal_centres_mm: tuple[tuple[float, float, float], ...] = ()  # per group (sphere)

    @property
    def duration_s(self) -> float:
        return float(sum(m.duration_s for m in self.moves))

    def moves_of_group(self, group: int) -> list[TouchMove]:
        return [m for m in self.moves if m.group == group]


def _commanded(x: np.ndarray, resolution_um: float) -> tuple[float, float, float]:
    """Start positions are commanded at the axis resolution."""
    if resolution_um > 0:
        step = resolution_um / 1000.0
        x = np.round(x / step) * step
    return (float(x[0]), float(x[1]), float(x[2]))


def sphere_touch_offsets(points: int, contact_radius_mm: float) -> np.ndarray:
    """Nominal tip-centre contact points relative to the sphere centre, (points, 3) mm:
    the pole and a ring 45 degrees below it."""
    if points < MIN_SPHERE_POINTS:
        raise PlanError(f"points_per_indexing: {points} is too few for a sphere fit "
                        f"(minimum {MIN_SPHERE_POINTS})")
    out = [np.array([0.0, 0.0, contact_radius_mm])]
    theta = math.radians(RING_POLAR_ANGLE_DEG)
    for j in range(points - 1):
        phi = 2.0 * math.pi * j / (points - 1)
        out.append(contact_radius_mm * np.array([math.sin(theta) * math.cos(phi),
                                                 math.sin(theta) * math.sin(phi),
                                                 math.cos(theta)]))
    return np.array(out)


def plan_sphere_cycle(geometry: ArtefactGeometry, c_angles_deg=DEFAULT_C_ANGLES_DEG,
                      points_per_indexing: int = DEFAULT_SPHERE_POINTS,
                      timing: SphereTiming = SphereTiming(), clearance_mm: float = 2.0,
                      b_axis_deg: float = 0.0) -> CyclePlan:
    """Moves of one sphere cycle. Each touch starts ``clearance_mm`` above its nominal
    contact point and may travel twice that before it counts as a missing trigger."""
    angles = tuple(float(a) for a in c_angles_deg)
    if not angles:
        raise PlanError("c_angles_deg: empty")
    for a in angles:
        if not math.isfinite(a) or abs(a) > 720.0:
            raise PlanError(f"c_angles_deg: {a!r} is not a C index within +-720 degrees")
    if clearance_mm <= 0:
        raise PlanError(f"clearance_mm: must be > 0, got {clearance_mm!r}")
    rho = geometry.contact_radius_mm
    offsets = sphere_touch_offsets(int(points_per_indexing), rho)
    res = geometry.probe.axis_resolution_um
    moves: list[TouchMove] = []
    centres = []
    n_groups = len(angles)
    for g_idx, c in enumerate(angles):
        centre = nominal_sphere_centre(c, geometry, b_axis_deg)
        centres.append(tuple(float(v) for v in centre))
        for p_idx, off in enumerate(offsets):
            duration = timing.touch_s
            if p_idx == 0:
                duration += timing.indexing_s
                if g_idx == 0:
                    duration += timing.tool_change_s
            if g_idx == n_groups - 1 and p_idx == len(offsets) - 1:
                duration += timing.tool_change_s
            start = centre + off + np.array([0.0, 0.0, clearance_mm])
            moves.append(TouchMove(
                artefact=ARTEFACT_SPHERE, c_axis_deg=c, b_axis_deg=float(b_axis_deg),
                start_mm=_commanded(start, res), direction=(0.0, 0.0, -1.0),
                max_travel_mm=2.0 * clearance_mm, duration_s=duration, group=g_idx,
                stage=f"C={c:g} point {p_idx + 1}/{len(offsets)}"))
    return CyclePlan(ARTEFACT_SPHERE, tuple(moves), angles, len(offsets), rho, tuple(centres))


def plan_guide_bush_cycle(geometry: ArtefactGeometry,
                          repeats: int = DEFAULT_GUIDE_BUSH_REPEATS,
                          timing: GuideBushTiming = GuideBushTiming(),
                          clearance_mm: float = 0.05) -> CyclePlan:
    """Moves of one guide-bush cycle: ``repeats`` torque-limit skips against the face."""
    if repeats < 1:
        raise PlanError(f"points_per_indexing: {repeats} repeats; at least 1 needed")
    if clearance_mm <= 0:
        raise PlanError(f"clearance_mm: must be > 0, got {clearance_mm!r}")
    gb = geometry.guide_bush
    approach = np.asarray(gb.approach_direction, dtype=float)
    approach = approach / np.linalg.norm(approach)
    y0, z0 = gb.face_centre_yz_mm
    face = np.array([gb.face_x_mm, y0, z0])
    start = face - approach * clearance_mm
    moves = []
    for k in range(repeats):
        duration = timing.touch_s + (timing.approach_s if k == 0 else 0.0)
        moves.append(TouchMove(
            artefact=ARTEFACT_GUIDE_BUSH, c_axis_deg=0.0, b_axis_deg=0.0,
            start_mm=_commanded(start, gb.level_spacing_um),
            direction=(float(approach[0]), float(approach[1]), float(approach[2])),
            max_travel_mm=2.0 * clearance_mm, duration_s=duration, group=0,
            stage=f"guide bush skip {k + 1}/{repeats}"))
    return CyclePlan(ARTEFACT_GUIDE_BUSH, tuple(moves), (), repeats, 0.0)
