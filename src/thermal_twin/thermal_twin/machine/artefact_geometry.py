"""Physical forward model of on-machine probing: where a probe really triggers (pure numpy).

Two reference artefacts: the precision sphere on the rotary table of a 5-axis machine and
the guide bush of a Swiss-type lathe. Their layout, the probes, how each location error
moves the sphere centre and how compensation enters are described in docs/twin.md
("Probing artefacts"). Bad input raises :class:`ValueError` naming the argument or key and
the value.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from thermal_comp_common.components import ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS
from thermal_comp_common.kinematics import rot_y

#: ISO 230-1 location errors of the C axis / table measured by the sphere cycle.
SPHERE_COMPONENTS = FIVE_AXIS_COMPONENTS
#: Angular components (um/m); the others are in um.
#: Error component of the guide-bush probing (tool side vs guide bush, X direction, um).
GUIDE_BUSH_COMPONENT = "GB_X"

ARTEFACT_SPHERE = 0       # same values as thermal_comp_msgs TouchProbe / ProbeCycle
ARTEFACT_GUIDE_BUSH = 1

UM_PER_MM = 1000.0


@dataclass(frozen=True)
class TouchProbeModel:
    """Touch-trigger probe on the spindle of the 5-axis machine.

    Sources: OMP60 repeatability 1 um at 2 sigma (thesis §5.1 and §7.3); Table 5.1 gives a
    command resolution of 1 um; the thesis calls the probe "2.5D", triggering only on moves
    in -Z (§5.1). The stylus tip is 6 mm in diameter (§7.3).
    """

    repeatability_2sigma_um: float = 1.0
    axis_resolution_um: float = 1.0            # 0 disables quantisation (ideal readout)
    stylus_tip_diameter_mm: float = 6.0
    supported_directions: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, -1.0),)
    direction_tolerance_deg: float = 0.5       # a move counts as along a supported direction

    @property
    def sigma_um(self) -> float:
        return self.repeatability_2sigma_um / 2.0


@dataclass(frozen=True)
class SphereArtefact:
    """Precision sphere on the rotary table. The nominal values are placement choices; the
    thesis gives only d/2 = 160 mm (its sphere diameter is a GAP)."""

    radius_from_c_axis_mm: float = 160.0       # d/2, thesis §5.2
    diameter_mm: float = 25.0                  # GAP in the thesis; a common calibration sphere
    centre_height_mm: float = 100.0            # sphere centre above the table surface
    c_axis_xy_mm: tuple[float, float] = (0.0, 0.0)   # C-axis line in machine X, Y
    # Machine zero is the C-axis point in the sphere-centre plane, where the seven errors
    # are defined: the HTM origin of cnc_bridge's default, so the defaults agree.
    table_surface_z_mm: float = -100.0         # table surface at B = 0
    b_pivot_z_mm: float = 0.0                  # B (swivel about Y) axis height, through the origin

    @property
    def d_m(self) -> float:
        """Distance between opposite sphere positions d, metres (eq. 5.8-5.10)."""
        return 2.0 * self.radius_from_c_axis_mm / 1000.0

    @property
    def centre_z_mm(self) -> float:
        return self.table_surface_z_mm + self.centre_height_mm


@dataclass(frozen=True)
class GuideBushArtefact:
    """Flat side face of the guide bush, probed with the torque-limit skip in X.

    Sources: repeatability within +-0.5 um, discrete skip levels, a constant sub-micrometre
    overstroke (AGP thesis §1.1, §1.5). The level spacing (0.1 um) and the noise sigma (so
    that +-0.5 um is 2.5 sigma) are assumptions; the thesis gives neither number.
    """

    face_x_mm: float = 12.0                    # X of the face (contact plane) at zero error
    face_centre_yz_mm: tuple[float, float] = (0.0, 0.0)
    face_half_size_mm: tuple[float, float] = (8.0, 8.0)   # extent of the face in Y, Z
    repeatability_um: float = 0.5              # bound of the scatter (clip)
    sigma_um: float = 0.2
    level_spacing_um: float = 0.1              # discrete position levels; 0 = continuous
    overstroke_um: float = 0.3                 # contact -> skip, constant for fixed Q and F
    approach_direction: tuple[float, float, float] = (-1.0, 0.0, 0.0)  # face normal opposite
    offset_axis_names: tuple[str, ...] = (GUIDE_BUSH_COMPONENT, "X")   # first present is used


@dataclass(frozen=True)
class ArtefactGeometry:
    """Default artefact geometry of a machine cell: sphere + probe, guide bush."""

    sphere: SphereArtefact = field(default_factory=SphereArtefact)
    probe: TouchProbeModel = field(default_factory=TouchProbeModel)
    guide_bush: GuideBushArtefact = field(default_factory=GuideBushArtefact)

    @property
    def contact_radius_mm(self) -> float:
        """Radius of the sphere the stylus-tip centre touches: sphere + tip radius."""
        return 0.5 * (self.sphere.diameter_mm + self.probe.stylus_tip_diameter_mm)


DEFAULT_GEOMETRY = ArtefactGeometry()


# --------------------------------------------------------------------------------------
def _finite_vector(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,):
        raise ValueError(f"{name}: expected 3 values, got shape {v.shape} ({value!r})")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: non-finite value {v.tolist()}")
    return v


def _finite_scalar(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: not a number: {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name}: non-finite value {v!r}")
    return v


def _get(mapping: Mapping[str, float], key: str, what: str) -> float:
    if key not in mapping:
        return 0.0
    return _finite_scalar(f"{what}['{key}']", mapping[key])


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def nominal_sphere_centre(c_axis_deg: float, geometry: ArtefactGeometry | None = None,
                          b_axis_deg: float = 0.0) -> np.ndarray:
    """Nominal sphere centre (machine coordinates, mm) at C index ``c_axis_deg``."""
    g = DEFAULT_GEOMETRY if geometry is None else geometry
    return true_sphere_centre(c_axis_deg, b_axis_deg, {}, {}, g)


def true_sphere_centre(c_axis_deg: float, b_axis_deg: float, errors: Mapping[str, float],
                       applied_offsets_um: Mapping[str, float],
                       geometry: ArtefactGeometry | None = None) -> np.ndarray:
    """Sphere centre as the CNC reads it (mm): true thermal location errors applied, minus
    the compensation offsets held in X, Y, Z."""
    g = DEFAULT_GEOMETRY if geometry is None else geometry
    s = g.sphere
    c = math.radians(_finite_scalar("c_axis_deg", c_axis_deg))
    b = math.radians(_finite_scalar("b_axis_deg", b_axis_deg))
    e = {k: _get(errors, k, "errors") for k in SPHERE_COMPONENTS}
    r = s.radius_from_c_axis_mm
    # Table frame: origin at the C-axis point in the sphere-centre plane. C' turns the
    # table by -C, so the sphere (at -X for C = 0) goes to +Y at C = 90.
    v0 = _rot_z(-c) @ np.array([-r, 0.0, 0.0])
    # Each error acts on the nominal geometry and the effects superpose: the thesis's
    # errors are first-order quantities, and products of two errors (below 1e-3 um here)
    # are not physics this model claims to know.
    v = (v0
         + v0 * (e["E_R0T"] / UM_PER_MM / r)                            # radial growth
         + (_rot_z(-e["E_C0C"] * 1e-6) @ v0 - v0)                       # zero position of C
         + (rot_y(e["E_B0C"] * 1e-6) @ _rot_x(e["E_A0C"] * 1e-6) @ v0 - v0)  # orientation
         + np.array([e["E_X0C"], e["E_Y0C"], e["E_Z0T"]]) / UM_PER_MM)
    p = v + np.array([s.c_axis_xy_mm[0], s.c_axis_xy_mm[1], s.centre_z_mm])
    if b != 0.0:  # swivel of the table about the B axis (parallel to Y)
        pivot = np.array([s.c_axis_xy_mm[0], 0.0, s.b_pivot_z_mm])
        p = pivot + rot_y(b) @ (p - pivot)
    off = np.array([_get(applied_offsets_um, k, "applied_offsets_um") for k in ("X", "Y", "Z")])
    return p - off / UM_PER_MM


def _along_supported(direction: np.ndarray, supported, tol_deg: float) -> bool:
    cos_tol = math.cos(math.radians(tol_deg))
    for d in supported:
        u = np.asarray(d, dtype=float)
        u = u / np.linalg.norm(u)
        if float(direction @ u) >= cos_tol:
            return True
    return False


def _quantise(x: np.ndarray, step_um: float) -> np.ndarray:
    if step_um <= 0.0:
        return x
    step = step_um / UM_PER_MM
    return np.round(x / step) * step


def _sphere_touch(c_deg, b_deg, start, direction, max_travel, errors, offsets, g, rng):
    probe = g.probe
    end = start + direction * max_travel
    if not _along_supported(direction, probe.supported_directions, probe.direction_tolerance_deg):
        return False, _quantise(end, probe.axis_resolution_um)   # the probe cannot trigger
    centre = true_sphere_centre(c_deg, b_deg, errors, offsets, g)
    rho = g.contact_radius_mm
    w = start - centre
    if float(w @ w) <= rho * rho:
        raise ValueError(f"start_mm {start.tolist()} lies inside the sphere (centre "
                         f"{centre.round(4).tolist()}, contact radius {rho} mm)")
    # |w + t*direction| = rho  ->  t^2 + 2 (w.d) t + |w|^2 - rho^2 = 0, first root
    bq = float(w @ direction)
    disc = bq * bq - (float(w @ w) - rho * rho)
    if disc < 0.0 or bq >= 0.0:
        return False, _quantise(end, probe.axis_resolution_um)
    t = -bq - math.sqrt(disc)
    if t > max_travel:
        return False, _quantise(end, probe.axis_resolution_um)
    if rng is not None and probe.sigma_um > 0.0:
        t += rng.normal(0.0, probe.sigma_um) / UM_PER_MM           # scatter along the move
    return True, _quantise(start + t * direction, probe.axis_resolution_um)


def _guide_bush_touch(start, direction, max_travel, errors, offsets, g, rng):
    gb = g.guide_bush
    end = start + direction * max_travel
    approach = np.asarray(gb.approach_direction, dtype=float)
    approach = approach / np.linalg.norm(approach)
    # torque-limit skip works along one axis only: moves must be along X
    if not _along_supported(direction, (tuple(approach), tuple(-approach)), 0.5):
        return False, _quantise(end, gb.level_spacing_um)
    if float(direction @ approach) < 0.0:
        return False, _quantise(end, gb.level_spacing_um)          # moving away from the face
    y0, z0 = gb.face_centre_yz_mm
    hy, hz = gb.face_half_size_mm
    if abs(start[1] - y0) > hy or abs(start[2] - z0) > hz:
        return False, _quantise(end, gb.level_spacing_um)          # passes beside the face
    error_um = _get(errors, GUIDE_BUSH_COMPONENT, "errors")
    offset_um = 0.0
    for name in gb.offset_axis_names:
        if name in offsets:
            offset_um = _get(offsets, name, "applied_offsets_um")
            break
    face_x = gb.face_x_mm + (error_um - offset_um) / UM_PER_MM
    # travel until the probe block reaches the face plane (approach is along -x or +x)
    t = (face_x - start[0]) / direction[0]
    if t < 0.0:
        raise ValueError(f"start_mm {start.tolist()} lies behind the guide-bush face "
                         f"(face at x = {face_x:.4f} mm)")
    t_skip = t + gb.overstroke_um / UM_PER_MM
    if t_skip > max_travel:
        return False, _quantise(end, gb.level_spacing_um)
    if rng is not None and gb.sigma_um > 0.0:
        noise = float(np.clip(rng.normal(0.0, gb.sigma_um), -gb.repeatability_um,
                              gb.repeatability_um))
        t_skip += noise / UM_PER_MM
    return True, _quantise(start + t_skip * direction, gb.level_spacing_um)


def split_compensation(errors: Mapping[str, float], applied: Mapping[str, float]
                       ) -> tuple[dict[str, float], dict[str, float]]:
    """Separate kinematic-model compensation (keys ``E_*``) from axis offsets.

    Returns (errors the machine still has where the probe touches, axis offsets). A CNC that
    holds the location errors in its kinematic model compensates them at every position, so
    they are subtracted from the true errors component by component.
    """
    kinematic = {k: v for k, v in applied.items() if k.startswith("E_")}
    if not kinematic:
        return dict(errors), dict(applied)
    residual = dict(errors)
    for k, v in kinematic.items():
        residual[k] = _get(residual, k, "errors") - _finite_scalar(f"applied_offsets_um['{k}']", v)
    return residual, {k: v for k, v in applied.items() if not k.startswith("E_")}


def touch_trigger_position(artefact: int, c_axis_deg: float, b_axis_deg: float,
                           start_mm: np.ndarray, direction: np.ndarray, max_travel_mm: float,
                           errors: Mapping[str, float], applied_offsets_um: Mapping[str, float],
                           geometry: ArtefactGeometry | None = None,
                           rng: np.random.Generator | None = None) -> tuple[bool, np.ndarray]:
    """Where the probe triggers when moved from ``start_mm`` along ``direction``.

    Parameters
    ----------
    artefact: ``ARTEFACT_SPHERE`` (0) or ``ARTEFACT_GUIDE_BUSH`` (1).
    c_axis_deg, b_axis_deg: rotary-axis positions (sphere only).
    start_mm, direction: start of the move (machine coordinates, mm) and its unit vector.
    max_travel_mm: if there is no trigger within this travel, the move ends untriggered.
    errors: true, uncompensated thermal errors: ``E_X0C E_Y0C E_Z0T E_R0T`` in um and
        ``E_A0C E_B0C E_C0C`` in um/m for the sphere; ``GB_X`` (um) for the guide bush.
        Missing keys count as 0. Other keys (further lathe tool positions) are ignored.
    applied_offsets_um: compensation the CNC holds. Axis offsets, axis name -> um: ``X Y Z``
        for the sphere; ``GB_X`` (else ``X``) for the guide bush. Or, when the CNC compensates
        in its kinematic model (the bridge's ``compensation_mode: kinematic``), location-error
        parameters by component name (``E_X0C`` .. ``E_C0C``, um or um/m): the CNC's 5-axis
        transformation then applies them at every position, so the probe sees
        ``errors[c] - applied[c]`` for each of them (:func:`split_compensation`).
    geometry: artefact geometry, default :data:`DEFAULT_GEOMETRY`.
    rng: source of the probe's repeatability scatter. ``None`` means no scatter; the
        readout quantisation (axis resolution, discrete skip levels) still applies.

    Returns
    -------
    ``(triggered, position_mm)``. ``position_mm`` is the axis position read at the skip
    (tip centre for the sphere), or, like a G31 that never skips, the end of the move.
    """
    g = DEFAULT_GEOMETRY if geometry is None else geometry
    errors, applied_offsets_um = split_compensation(errors, applied_offsets_um)
    start = _finite_vector("start_mm", start_mm)
    d = _finite_vector("direction", direction)
    n = float(np.linalg.norm(d))
    if abs(n - 1.0) > 1e-3:
        raise ValueError(f"direction: must be a unit vector, |direction| = {n:.6g} "
                         f"({d.tolist()})")
    d = d / n
    travel = _finite_scalar("max_travel_mm", max_travel_mm)
    if travel <= 0.0:
        raise ValueError(f"max_travel_mm: must be > 0, got {travel!r}")
    if artefact == ARTEFACT_SPHERE:
        return _sphere_touch(c_axis_deg, b_axis_deg, start, d, travel, errors,
                             applied_offsets_um, g, rng)
    if artefact == ARTEFACT_GUIDE_BUSH:
        return _guide_bush_touch(start, d, travel, errors, applied_offsets_um, g, rng)
    raise ValueError(f"artefact: unknown artefact {artefact!r} (0 = sphere, 1 = guide bush)")
