"""Least-squares fit of a sphere centre with known radius from touch-trigger points.

Each point is a tip-centre position read at a trigger, together with the direction of its
probing move. The probe scatters along its move, not along the surface normal, so the
residual of a point is the distance along the move between where it triggered and where
a sphere at the candidate centre would have made it trigger. With this residual the
covariance of the centre, ``sigma^2 (J^T J)^-1``, is the probe model propagated through
the fit geometry. ``sigma`` is the a-priori standard uncertainty of one trigger
(repeatability and readout resolution); the RMS residual is reported beside it.

The unknowns are scaled in micrometres relative to the initial guess, which keeps
``scipy.optimize.least_squares`` well conditioned.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

UM_PER_MM = 1000.0


class SphereFitError(ValueError):
    """The points do not determine a sphere centre (too few, degenerate, no convergence)."""


@dataclass(frozen=True)
class SphereFit:
    centre_mm: np.ndarray          # (3,)
    covariance_um2: np.ndarray     # (3, 3) covariance of the centre, um^2
    residuals_um: np.ndarray       # (n,) along each probing move, um
    rms_residual_um: float

    @property
    def std_um(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance_um2))


def probe_point_sigma_um(repeatability_sigma_um: float, resolution_um: float) -> float:
    """Standard uncertainty of one trigger along its move: scatter plus the readout
    resolution, a uniform distribution of width ``resolution_um`` (GUM type B)."""
    return math.sqrt(repeatability_sigma_um ** 2 + resolution_um ** 2 / 12.0)


def _along_move_residuals(centre_um: np.ndarray, points_um: np.ndarray,
                          directions: np.ndarray, radius_um: float) -> np.ndarray:
    w = points_um - centre_um                       # from the centre to each point
    wd = np.einsum("ij,ij->i", w, directions)
    ww = np.einsum("ij,ij->i", w, w)
    disc = wd * wd - (ww - radius_um * radius_um)
    out = np.empty(len(points_um))
    hit = disc >= 0.0
    # entering root of |w + s d| = R; the residual is -s (the point lies s before the hit)
    out[hit] = wd[hit] + np.sqrt(disc[hit])
    # the line passes beside the candidate sphere: use the radial distance instead so the
    # optimiser still sees a smooth, growing residual
    out[~hit] = np.sqrt(ww[~hit]) - radius_um
    return out


def _along_move_jacobian(centre_um: np.ndarray, points_um: np.ndarray,
                         directions: np.ndarray, radius_um: float) -> np.ndarray:
    """d residual / d centre, (n, 3): -d + (w - (w.d) d) / sqrt(disc) on the hit branch."""
    w = points_um - centre_um
    wd = np.einsum("ij,ij->i", w, directions)
    ww = np.einsum("ij,ij->i", w, w)
    disc = wd * wd - (ww - radius_um * radius_um)
    out = np.empty((len(points_um), 3))
    hit = disc > 1e-9 * radius_um * radius_um          # away from a grazing line
    root = np.sqrt(disc[hit])[:, None]
    out[hit] = -directions[hit] + (w[hit] - wd[hit, None] * directions[hit]) / root
    out[~hit] = -w[~hit] / np.sqrt(ww[~hit])[:, None]
    return out


def fit_sphere_centre(points_mm: np.ndarray, directions: np.ndarray, radius_mm: float,
                      point_sigma_um: float, initial_centre_mm: np.ndarray) -> SphereFit:
    """Centre of a sphere of known ``radius_mm`` through ``points_mm`` (n, 3)."""
    pts = np.asarray(points_mm, dtype=float)
    dirs = np.asarray(directions, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or dirs.shape != pts.shape:
        raise SphereFitError(f"points_mm/directions: expected matching (n, 3) arrays, "
                             f"got {pts.shape} and {dirs.shape}")
    if len(pts) < 4:
        raise SphereFitError(f"{len(pts)} points: at least 4 are needed for a centre "
                             f"with a residual")
    if not np.all(np.isfinite(pts)):
        raise SphereFitError("points_mm: non-finite coordinates")
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = np.asarray(initial_centre_mm, dtype=float)
    pts_um = (pts - origin) * UM_PER_MM
    r_um = radius_mm * UM_PER_MM

    def fun(c):
        return _along_move_residuals(c, pts_um, dirs, r_um)

    def jac(c):
        return _along_move_jacobian(c, pts_um, dirs, r_um)

    sol = least_squares(fun, np.zeros(3), jac=jac, method="lm", x_scale=1.0, xtol=1e-12,
                        ftol=1e-12, gtol=1e-12)
    if not sol.success:
        raise SphereFitError(f"sphere fit did not converge: {sol.message}")
    jac = sol.jac
    jtj = jac.T @ jac
    if np.linalg.matrix_rank(jtj, tol=1e-9 * max(1.0, np.abs(jtj).max())) < 3:
        raise SphereFitError("the touch points do not determine the centre "
                             "(rank-deficient fit geometry)")
    cov = point_sigma_um ** 2 * np.linalg.inv(jtj)
    res = np.asarray(sol.fun, dtype=float)
    return SphereFit(centre_mm=origin + sol.x / UM_PER_MM, covariance_um2=cov,
                     residuals_um=res, rms_residual_um=float(np.sqrt(np.mean(res ** 2))))
