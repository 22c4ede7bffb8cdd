"""Choosing temperature sensors: unique sensor groups (k-means with a WCSS elbow, lathe thesis
§5.1), the calibration length they imply, one medoid sensor per group, and the sensor whose fast
part the errors follow. Used by the AGP (calibration length) and by the benchmarks (inputs).
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from sklearn.cluster import KMeans

from talc_model.open_loop.lagged_temperature_model import exponential_filter
from thermal_comp_common.runtime.blas_threads import single_thread_blas


#: Low-pass time constant that separates fast parts for :func:`fast_sensor` (s): the spindle-nose scale.
FAST_SENSOR_TAU_S = 1800.0


class SensorSelectionError(ValueError):
    """Bad input to a sensor selection; the message names the argument and value."""


@dataclass
class SensorGroups:
    n_groups: int
    labels: list[int]
    wcss: list[float]          # within-cluster sum of squares for k = 0 (about zero), 1, 2, ...


def sensor_groups(series, *, max_groups: int = 10, seed: int = 0) -> SensorGroups:
    """Unique input groups: k-means over the sensors (as samples) of their standardised time
    series, number of groups from the WCSS elbow (thesis §5.1, Fig. 5.2).

    Each sensor's series is z-scored, so mutually correlated sensors lie close together. The
    elbow is the point of the WCSS curve farthest from the chord between k = 0 (all series
    about the zero vector, WCSS = total sum of squares) and k = k_max; the k = 0 anchor lets
    a single group of correlated sensors show its elbow at k = 1 (our choice; the thesis reads
    the elbow by eye). Constant sensors carry no information and form no group of their own.
    """
    s = np.asarray(series, dtype=float)
    if s.ndim != 2:
        raise SensorSelectionError(f"sensor series: expected (time, sensors), got shape {s.shape}")
    s = s[np.all(np.isfinite(s), axis=1)]
    if s.shape[0] < 3:
        raise SensorSelectionError(f"sensor series: needs >= 3 complete rows, got {s.shape[0]}")
    std = s.std(axis=0)
    moving = std > 1e-9
    labels = [-1] * s.shape[1]
    if not moving.any():
        return SensorGroups(1, [0] * s.shape[1], [0.0])
    z = ((s[:, moving] - s[:, moving].mean(axis=0)) / std[moving]).T   # sensors x time
    p = z.shape[0]
    k_max = min(max_groups, p)
    wcss = [float(np.sum(z ** 2))]
    fits = {}
    for k in range(1, k_max + 1):
        with single_thread_blas(openmp=True):   # tiny problem: OpenMP threads only contend on a shared machine
            km = KMeans(n_clusters=k, n_init=10, random_state=seed).fit(z)
        fits[k] = km
        wcss.append(float(km.inertia_))
    ks = np.arange(0, k_max + 1, dtype=float)
    w = np.asarray(wcss)
    if k_max == 1:
        n_groups = 1
    else:
        # distance of (k, W_k) from the chord (0, W_0)-(k_max, W_kmax), both axes normalised
        kx = ks / k_max
        wy = (w - w[-1]) / max(w[0] - w[-1], 1e-12)
        dist = np.abs((1 - kx) - wy) / math.sqrt(2.0)   # chord: wy = 1 - kx
        n_groups = int(np.argmax(dist[1:]) + 1)
    moving_labels = fits[n_groups].labels_.tolist()
    it = iter(moving_labels)
    labels = [int(next(it)) if m else -1 for m in moving]
    return SensorGroups(n_groups, labels, wcss)


def calibration_points_needed(series, *, points_per_group: int = 10, max_groups: int = 10,
                              seed: int = 0) -> tuple[int, SensorGroups]:
    """N_min = points_per_group x unique sensor groups (Loeppky's 10 x rule, thesis §5.1)."""
    groups = sensor_groups(series, max_groups=max_groups, seed=seed)
    return points_per_group * groups.n_groups, groups


def sensor_medoids(temperatures: np.ndarray, n_groups: int, names: Sequence[str], seed: int = 0) -> list[str]:
    """One representative sensor per k-means group of the z-scored temperature series.

    The medoid is the member closest to its group centre; returned in sensor order.
    """
    T = np.asarray(temperatures, dtype=float)
    if T.ndim != 2 or T.shape[1] != len(names):
        raise SensorSelectionError(f"temperatures: shape {T.shape} does not match {len(names)} sensor names")
    if not 1 <= n_groups <= T.shape[1]:
        raise SensorSelectionError(f"n_groups: {n_groups!r} must be in 1..{T.shape[1]}")
    sd = T.std(axis=0)
    z = ((T - T.mean(axis=0)) / np.where(sd > 1e-12, sd, 1.0)).T     # sensors x time
    with single_thread_blas(openmp=True):
        km = KMeans(n_clusters=n_groups, n_init=10, random_state=seed).fit(z)
    picks = []
    for g in range(n_groups):
        idx = np.flatnonzero(km.labels_ == g)
        picks.append(int(idx[np.argmin(np.sum((z[idx] - km.cluster_centers_[g]) ** 2, axis=1))]))
    return [names[i] for i in sorted(picks)]


def fast_sensor(time_s: np.ndarray, temperatures: np.ndarray, displacements: np.ndarray, names: Sequence[str],
                tau_s: float = FAST_SENSOR_TAU_S) -> str:
    """The sensor whose fast part best follows the displacements' fast parts on the given
    (calibration) rows: largest mean |correlation| over the channels between x - LP(x), with LP
    a causal first-order low-pass of time constant ``tau_s``, of temperature and displacement.
    On FL_THERMAL it is t4 in every walk-forward fold and for tau 10-60 min (the spindle-near
    sensor; ch3/ch4's 30-min wiggles follow it by ~2 min)."""
    t = np.asarray(time_s, dtype=float)
    T = np.asarray(temperatures, dtype=float)
    D = np.asarray(displacements, dtype=float)
    D = D[:, None] if D.ndim == 1 else D
    if T.ndim != 2 or T.shape[1] != len(names) or T.shape[0] != t.size or D.shape[0] != t.size or t.size < 3:
        raise SensorSelectionError(f"temperatures {T.shape} / displacements {D.shape}: need N x {len(names)} and "
                                   f"N x channels for the {t.size} rows of time_s (N >= 3)")
    fT = T - exponential_filter(t, T, float(tau_s))
    fD = D - exponential_filter(t, D, float(tau_s))
    fT, fD = fT - fT.mean(axis=0), fD - fD.mean(axis=0)
    norm = np.sqrt(np.outer((fT ** 2).sum(axis=0), (fD ** 2).sum(axis=0)))
    corr = np.abs(fT.T @ fD) / np.where(norm > 0, norm, np.inf)
    return names[int(np.argmax(corr.mean(axis=1)))]
