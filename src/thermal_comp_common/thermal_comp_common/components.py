"""The seven location errors of the 5-axis machine (ISO 230-7 names), defined once.

``E_X0C E_Y0C`` position of the C-axis line, ``E_Z0T`` table height, ``E_R0T`` radial
(table diameter) growth: micrometres; ``E_A0C E_B0C E_C0C`` C-axis tilts and the
rotation of its zero: micrometres per metre. Every package names them through this module.
"""
from __future__ import annotations

LINEAR_COMPONENTS = ("E_X0C", "E_Y0C", "E_Z0T", "E_R0T")           # um
ANGULAR_COMPONENTS = ("E_A0C", "E_B0C", "E_C0C")                  # um/m
FIVE_AXIS_COMPONENTS = LINEAR_COMPONENTS + ANGULAR_COMPONENTS


def is_angular(component: str) -> bool:
    """True for the angular location errors (um/m), False for linear ones and other channels (um)."""
    return component in ANGULAR_COMPONENTS


def unit_of(component: str) -> str:
    """``"um/m"`` for an angular location error, else ``"um"``."""
    return "um/m" if is_angular(component) else "um"
