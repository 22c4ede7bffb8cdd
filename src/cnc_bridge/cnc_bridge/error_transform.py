"""Predicted thermal errors -> axis offsets (pure core, no ROS).

5-axis table machine (Blaser's TALC, thesis §6.4.1, eq. 6.3-6.5; two sign conventions, see
:func:`five_axis_offsets_um`): a rigid-body homogeneous-transformation model maps the seven location errors of the C axis / table

    E_X0C, E_Y0C, E_Z0T, E_R0T   in micrometres (um)
    E_A0C, E_B0C, E_C0C          in micrometres per metre (um/m, i.e. urad)

at the nominal axis positions X, Y, Z [mm] (zero at the machine's coordinate origin of
thesis Fig. 6.11) and the swivel angle B [deg] (zero with the table surface parallel to X)
to the error of the tool centre point along the machine axes X, Y, Z in um.

Units, made explicit: an angular error in um/m times a position in mm gives
``E [um/m] * pos [mm] * 1e-3 = um``; E_R0T is the radial growth measured at the sphere
eccentricity d/2 [mm] and scales linearly with radius, so it enters as ``E_R0T * pos / (d/2)``.

Sign convention (the same as AxisOffsets.msg): the offset is the predicted error itself;
the CNC holds it as a compensation so that what a probe then sees is
``true error - applied offset`` (the axis origin is shifted opposite to the error).

Swiss-type lathe (Kaftan's AGP thesis, §6.3): the model predicts the error at the
torque-limit-skip (TLS) position, usually the guide bush (component ``GB_X``); every
other tool position k gets ``e_k = e_TLS + delta_k`` where ``delta_k = e_k - e_TLS`` comes
from a per-tool offset model trained offline in a multiple-TCP training test, unless
the prediction itself already carries the tool's component.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import yaml
from thermal_comp_common.components import ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS, LINEAR_COMPONENTS
from thermal_comp_common.kinematics import TransformInputError, finite_input, rot_y

#: The seven C-axis / table errors of a 5-axis machine, in the order of the thesis.
#: Axes the 5-axis offsets are written to (B and C are not compensated: their 0.001 deg
#: command resolution, ~17.5 um/m, is of the order of the angular errors themselves).
FIVE_AXIS_OFFSET_AXES = ("X", "Y", "Z")
#: Sphere eccentricity d/2 of the thesis' set-up (d = 0.32 m).
DEFAULT_SPHERE_RADIUS_MM = 160.0

_UM_PER_M_TIMES_MM_TO_UM = 1e-3


#: Conventions for eq. 6.3-6.5 (see :func:`five_axis_offsets_um`).
CONVENTION_RIGID = "rigid"
CONVENTION_PRINTED = "printed"
CONVENTIONS = (CONVENTION_RIGID, CONVENTION_PRINTED)


@dataclass(frozen=True)
class HtmGeometry:
    """Where the HTM origin is: the point the seven errors are defined at.

    ``origin_mm``: machine coordinates (mm) at B = 0 of the C-axis point in the plane the
    errors refer to (the sphere-centre plane of the probing cycle: E_X0C/E_Y0C are the C
    line's position there, the tilts pivot about it). ``b_pivot_xz_mm``: the B axis (parallel
    to Y) passes through X, Z = these values; B swivels the origin with the table.
    Defaults: origin at the machine zero, B through it.
    """

    origin_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    b_pivot_xz_mm: tuple[float, float] = (0.0, 0.0)

    def origin_at_mm(self, b_deg: float) -> np.ndarray:
        """Machine coordinates of the origin with the table swivelled to B [deg], mm."""
        b = math.radians(b_deg)
        px, pz = self.b_pivot_xz_mm
        ox, oy, oz = self.origin_mm
        dx, dz = ox - px, oz - pz
        return np.array([px + math.cos(b) * dx + math.sin(b) * dz, oy,
                         pz - math.sin(b) * dx + math.cos(b) * dz])

    def relative_position_mm(self, x_mm: float, y_mm: float, z_mm: float, b_deg: float) -> np.ndarray:
        """Machine position minus the origin (swivelled by B), in machine axes, mm."""
        return np.array([x_mm, y_mm, z_mm]) - self.origin_at_mm(b_deg)


def five_axis_offsets_um(errors: Mapping[str, float], x_mm: float, y_mm: float, z_mm: float,
                         b_deg: float, sphere_radius_mm: float = DEFAULT_SPHERE_RADIUS_MM,
                         convention: str = CONVENTION_RIGID) -> dict[str, float]:
    """The seven errors at position (X, Y, Z [mm] relative to the HTM origin, B [deg]) -> {X, Y, Z} um.

    ``errors`` maps component name -> value (um for E_X0C..E_R0T, um/m for E_A0C..E_C0C);
    a missing component is an error (a model that does not predict one must send 0).

    ``convention``:

    * ``"printed"``: eq. 6.3-6.5 exactly as printed in the thesis.
    * ``"rigid"`` (default): the rigid-body homogeneous transformation with the error
      definitions of the probing cycle (eq. 5.4-5.10, as ``thermal_twin.machine.artefact_geometry``
      implements them): in the table frame (position p_t = R_y(B)^T p) the error is
      ``(E_X0C, E_Y0C, E_Z0T) + E_R0T (x_t, y_t, 0)/(d/2) + w x p_t`` with the small
      rotation ``w = (E_A0C, E_B0C, -E_C0C) * 1e-6`` rad, then turned by R_y(B) into machine
      axes. At B = 0 and 90 deg it equals eq. 6.3-6.5 except for two signs: E_C0C (the
      table is C', turned by -E_C0C, as eq. 5.10 measures it; eq. 6.3/6.4 use +E_C0C, which
      would double the error instead of cancelling it) and the E_A0C*Z term of eq. 6.4
      (printed +, which no rigid tilt about X produces together with the printed
      +E_A0C*Y in eq. 6.5). At other B it is exact where eq. 6.3-6.5 are not: their
      E_R0T terms use X*cos B and Z*sin B instead of the table-frame radius.
    """
    if not sphere_radius_mm > 0.0:
        raise TransformInputError(f"'sphere_radius_mm' must be > 0, got {sphere_radius_mm!r}")
    if convention not in CONVENTIONS:
        raise TransformInputError(f"'convention' must be one of {CONVENTIONS}, got {convention!r}")
    e = {}
    for name in FIVE_AXIS_COMPONENTS:
        if name not in errors:
            raise TransformInputError(
                f"error component '{name}' missing (got {sorted(errors)})")
        e[name] = finite_input(name, errors[name])
    x, y, z = finite_input("X", x_mm), finite_input("Y", y_mm), finite_input("Z", z_mm)
    b = math.radians(finite_input("B", b_deg))
    k = _UM_PER_M_TIMES_MM_TO_UM
    r = sphere_radius_mm
    ex, ey, ezt, ert = e["E_X0C"], e["E_Y0C"], e["E_Z0T"], e["E_R0T"]
    ea, eb, ec = e["E_A0C"], e["E_B0C"], e["E_C0C"]
    if convention == CONVENTION_PRINTED:
        cb, sb = math.cos(b), math.sin(b)
        off_x = (eb * z * k
                 + (ex + ert * x / r - ec * y * k) * cb
                 + (ezt + ea * y * k) * sb)
        off_y = (ey + ert * y / r
                 + (ea * z * k + ec * x * k) * cb
                 - (ea * x * k + ec * z * k) * sb)
        off_z = (-eb * x * k
                 + (ezt + ea * y * k) * cb
                 + (-ex + ert * z / r + ec * y * k) * sb)
        return {"X": off_x, "Y": off_y, "Z": off_z}
    rot = rot_y(b)
    p_t = rot.T @ np.array([x, y, z])
    w = np.array([ea, eb, -ec]) * k              # um/m * mm * 1e-3 = um per mm of lever
    e_t = (np.array([ex, ey, ezt]) + ert * np.array([p_t[0], p_t[1], 0.0]) / r
           + np.cross(w, p_t))
    off = rot @ e_t
    return {"X": float(off[0]), "Y": float(off[1]), "Z": float(off[2])}


@dataclass(frozen=True)
class ToolOffsetModel:
    """delta_k = e_k - e_TLS for one tool position, linear in the TLS error.

    ``delta_um = intercept_um + gain * e_TLS_um``: the simplest model a multiple-TCP
    training test can identify without the tool-position temperatures (the bridge sees
    errors, not temperatures); a temperature-driven offset model belongs in the error
    model and then arrives as the tool's own component in the prediction.
    """

    intercept_um: float = 0.0
    gain: float = 0.0

    def delta_um(self, tls_error_um: float) -> float:
        return self.intercept_um + self.gain * tls_error_um


def fit_tool_offset_model(tls_error_um, tool_error_um) -> ToolOffsetModel:
    """Least-squares fit of a :class:`ToolOffsetModel` to training pairs (e_TLS, e_k) in um."""
    e_tls = np.asarray(tls_error_um, dtype=float).ravel()
    e_k = np.asarray(tool_error_um, dtype=float).ravel()
    if e_tls.shape != e_k.shape:
        raise TransformInputError(
            f"tls_error_um has {e_tls.size} samples but tool_error_um has {e_k.size}")
    if e_tls.size < 2 or not (np.all(np.isfinite(e_tls)) and np.all(np.isfinite(e_k))):
        raise TransformInputError("need at least 2 finite training pairs to fit a tool offset model")
    design = np.column_stack([np.ones_like(e_tls), e_tls])
    (intercept, gain), *_ = np.linalg.lstsq(design, e_k - e_tls, rcond=None)
    return ToolOffsetModel(intercept_um=float(intercept), gain=float(gain))


@dataclass(frozen=True)
class LatheToolOffsets:
    """Per-tool offsets of a Swiss-type lathe from the TLS (guide-bush) prediction.

    ``tls_component``: the predicted component at the TLS position (e.g. ``GB_X``); it is
    itself an offset axis. ``tools``: offset axis name (e.g. ``T01_X``) -> its offset model.
    """

    tls_component: str = "GB_X"
    tools: Mapping[str, ToolOffsetModel] = field(default_factory=dict)

    def offsets_um(self, errors: Mapping[str, float]) -> dict[str, float]:
        if self.tls_component not in errors:
            raise TransformInputError(
                f"TLS component '{self.tls_component}' missing (got {sorted(errors)})")
        e_tls = finite_input(self.tls_component, errors[self.tls_component])
        out = {self.tls_component: e_tls}
        for tool, model in self.tools.items():
            if tool in errors:      # the error model already predicted this tool position
                out[tool] = finite_input(tool, errors[tool])
            else:
                out[tool] = e_tls + model.delta_um(e_tls)
        return out

    @staticmethod
    def from_mapping(spec: Mapping) -> "LatheToolOffsets":
        """Build from a YAML/JSON mapping ``{tls_component: GB_X, tools: {T01_X: {intercept_um, gain}}}``."""
        if not isinstance(spec, Mapping):
            raise TransformInputError(f"lathe tool offsets: expected a mapping, got {type(spec).__name__}")
        tls = spec.get("tls_component", "GB_X")
        if not isinstance(tls, str) or not tls:
            raise TransformInputError(f"lathe tool offsets: 'tls_component' must be a name, got {tls!r}")
        tools_spec = spec.get("tools", {}) or {}
        if not isinstance(tools_spec, Mapping):
            raise TransformInputError(f"lathe tool offsets: 'tools' must be a mapping, got {tools_spec!r}")
        tools = {}
        for name, m in tools_spec.items():
            m = m or {}
            unknown = set(m) - {"intercept_um", "gain"}
            if unknown:
                raise TransformInputError(
                    f"lathe tool offsets: tools.{name}: unknown key(s) {sorted(unknown)}")
            tools[str(name)] = ToolOffsetModel(
                intercept_um=finite_input(f"tools.{name}.intercept_um", m.get("intercept_um", 0.0)),
                gain=finite_input(f"tools.{name}.gain", m.get("gain", 0.0)))
        return LatheToolOffsets(tls_component=tls, tools=tools)


def offsets_from_errors(errors: Mapping[str, float], axis_positions: Mapping[str, float],
                        sphere_radius_mm: float = DEFAULT_SPHERE_RADIUS_MM,
                        lathe: LatheToolOffsets | None = None,
                        geometry: HtmGeometry | None = None,
                        convention: str = CONVENTION_RIGID) -> dict[str, float]:
    """Offsets (axis -> um) for whatever machine kind the error components describe.

    Components E_X0C.. -> 5-axis HTM at ``axis_positions`` (machine X, Y, Z in mm, made
    relative to ``geometry``'s origin; B in deg, a missing B means a machine without
    swivel, B = 0); otherwise the lathe mapping.
    """
    if any(name in errors for name in FIVE_AXIS_COMPONENTS):
        pos = {}
        for axis in ("X", "Y", "Z"):
            if axis not in axis_positions:
                raise TransformInputError(
                    f"axis position '{axis}' unknown (machine_state gave {sorted(axis_positions)})")
            pos[axis] = axis_positions[axis]
        b = finite_input("B", axis_positions.get("B", 0.0))
        rel = (geometry or HtmGeometry()).relative_position_mm(
            finite_input("X", pos["X"]), finite_input("Y", pos["Y"]), finite_input("Z", pos["Z"]), b)
        return five_axis_offsets_um(errors, *rel, b_deg=b, sphere_radius_mm=sphere_radius_mm,
                                    convention=convention)
    return (lathe or LatheToolOffsets()).offsets_um(errors)


def load_lathe_tools(path: str) -> LatheToolOffsets | None:
    """The lathe's tool-offset models from a YAML file (``lathe_tools_file``); None without a path."""
    if not path:
        return None
    try:
        with open(path, encoding="utf-8") as f:
            return LatheToolOffsets.from_mapping(yaml.safe_load(f))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ValueError(f"parameter 'lathe_tools_file': {exc}") from exc
