"""The seven C-axis / table location errors from four sphere centres (Blaser 2020, eq. 5.4-5.10).

With p[k] the sphere centre (um) at C = 0, 90, 180, 270 degrees (k = 1..4; the sphere at
-X, +Y, +X, -Y of the C axis) and d the distance between opposite sphere positions (m):

    E_X0C = 1/4 sum_k p[k].x                      (5.4)
    E_Y0C = 1/4 sum_k p[k].y                      (5.5)
    E_Z0T = 1/4 sum_k p[k].z                      (5.6)
    E_R0T = 1/4 (p3.x + p2.y - p1.x - p4.y)       (5.7)
    E_A0C = 1/d (p2.z - p4.z)                     (5.8)   um/m
    E_B0C = 1/d (p1.z - p3.z)                     (5.9)   um/m
    E_C0C = 1/(2d) (p1.y + p2.x - p3.y - p4.x)    (5.10)  um/m

Each formula is evaluated for cycle i minus the same formula for the reference cycle. They
are linear, so they are one 7 x 12 matrix M acting on the stacked centre differences,
and the covariance of the errors is M (Sigma_i + Sigma_ref) M^T (the two cycles are
independent).
"""
from __future__ import annotations

import numpy as np

from thermal_twin.machine.artefact_geometry import SPHERE_COMPONENTS

#: C index of the sphere positions k = 1..4 used by eq. 5.4-5.10.
EQUATION_C_ANGLES_DEG = (0.0, 90.0, 180.0, 270.0)


def location_error_matrix(d_m: float) -> np.ndarray:
    """M (7 x 12): errors (um, um/m) = M @ [p1x p1y p1z p2x ... p4z] (um)."""
    if not d_m > 0:
        raise ValueError(f"d_m: distance between opposite sphere positions must be > 0, "
                         f"got {d_m!r}")
    m = np.zeros((7, 12))

    def idx(k: int, axis: str) -> int:           # k = 1..4
        return 3 * (k - 1) + "xyz".index(axis)

    for k in range(1, 5):
        m[0, idx(k, "x")] = 0.25
        m[1, idx(k, "y")] = 0.25
        m[2, idx(k, "z")] = 0.25
    for k, axis, sign in ((3, "x", 1), (2, "y", 1), (1, "x", -1), (4, "y", -1)):
        m[3, idx(k, axis)] = 0.25 * sign
    m[4, idx(2, "z")], m[4, idx(4, "z")] = 1.0 / d_m, -1.0 / d_m
    m[5, idx(1, "z")], m[5, idx(3, "z")] = 1.0 / d_m, -1.0 / d_m
    for k, axis, sign in ((1, "y", 1), (2, "x", 1), (3, "y", -1), (4, "x", -1)):
        m[6, idx(k, axis)] = sign / (2.0 * d_m)
    return m


def location_errors(centres_um: np.ndarray, reference_centres_um: np.ndarray, d_m: float,
                    covariances_um2: np.ndarray | None = None,
                    reference_covariances_um2: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Errors of one cycle relative to the reference, and their standard uncertainties.

    ``centres_um`` and ``reference_centres_um``: (4, 3), k = 1..4.
    ``covariances_um2``: (4, 3, 3) per centre (None = exact). Returns ``(values,
    uncertainties)``, each (7,), in the order of :data:`SPHERE_COMPONENTS`.
    """
    p = np.asarray(centres_um, dtype=float)
    p_ref = np.asarray(reference_centres_um, dtype=float)
    if p.shape != (4, 3) or p_ref.shape != (4, 3):
        raise ValueError(f"centres: expected (4, 3) arrays, got {p.shape} and {p_ref.shape}")
    m = location_error_matrix(d_m)
    values = m @ (p - p_ref).reshape(12)
    cov = np.zeros((12, 12))
    for covs in (covariances_um2, reference_covariances_um2):
        if covs is None:
            continue
        c = np.asarray(covs, dtype=float)
        if c.shape != (4, 3, 3):
            raise ValueError(f"covariances: expected (4, 3, 3), got {c.shape}")
        for k in range(4):
            cov[3 * k:3 * k + 3, 3 * k:3 * k + 3] += c[k]
    u = np.sqrt(np.clip(np.diag(m @ cov @ m.T), 0.0, None))
    return values, u


__all__ = ["EQUATION_C_ANGLES_DEG", "SPHERE_COMPONENTS", "location_error_matrix",
           "location_errors"]
