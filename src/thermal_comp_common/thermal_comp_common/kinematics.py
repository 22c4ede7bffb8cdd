"""Kinematics shared by the models and the bridge: what held X/Y/Z offsets are in error terms.

The 5-axis location errors (:mod:`thermal_comp_common.components`) live in the table frame,
the axis offsets in machine axes; the B axis (parallel to Y) turns one into the other. The
bridge writes offsets, a model learning from probes needs them as components: both use this
one mapping (pure, numpy only).
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np


class TransformInputError(ValueError):
    """An error component or axis position is missing or not a finite number."""


def finite_input(name: str, value: float) -> float:
    """``value`` as a float, or :class:`TransformInputError` naming ``name`` if it is not finite."""
    v = float(value)
    if not math.isfinite(v):
        raise TransformInputError(f"'{name}' must be a finite number, got {value!r}")
    return v


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation matrix about Y (the B axis) by ``angle_rad``."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def applied_offsets_in_component_space(applied_offsets_um: Mapping[str, float],
                                       b_deg: float = 0.0) -> dict[str, float]:
    """What constant X/Y/Z offsets compensate, expressed as the seven 5-axis components.

    A probing cycle that touches the artefact at several C indexings with the same X/Y/Z
    offsets held sees them as a pure translation of the table frame: it lowers the measured
    E_X0C, E_Y0C, E_Z0T by ``R_y(B)^T * offset`` and leaves E_R0T, E_A0C, E_B0C, E_C0C
    untouched (they come from differences between indexings). So a model that rebuilds the
    total error as "measured residual + applied compensation" must add back exactly this,
    not its whole prediction (the rest was never applied where the probe looks).
    Missing axes count as 0.
    """
    off = np.array([finite_input(f"applied_offsets_um.{a}", applied_offsets_um.get(a, 0.0))
                    for a in ("X", "Y", "Z")])
    t = rot_y(math.radians(finite_input("B", b_deg))).T @ off
    return {"E_X0C": float(t[0]), "E_Y0C": float(t[1]), "E_Z0T": float(t[2]),
            "E_R0T": 0.0, "E_A0C": 0.0, "E_B0C": 0.0, "E_C0C": 0.0}
