"""Load-case update of characteristic diagrams from measurements ([002 §3.2], production case):
per sample a temporary geometric CD through the base model's support-point values and the
measured points (weights 1 : 10), then one temperature-input update CD per support point.
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from thermal_comp_common.metrics import rmse

from talc_model.cd.diagram import CharacteristicDiagram, CharacteristicDiagramError, as_2d


@dataclass
class MeasurementUpdate:
    """Update CDs per support point (temperature inputs) from measured relative displacements.

    ``predict(temperatures)`` gives the additive correction of every support point, shape
    (samples, support points); the base model's support-point values plus this are the updated
    ones, which the usual geometric interpolation then carries to the TCP.
    """

    inputs: list[int]                          # temperature columns the update CDs use
    cds: list[CharacteristicDiagram]           # one per support point
    adjusted: np.ndarray                       # (samples, support points) after step C
    rmse_before: float                         # base model vs measurements at the measured points
    rmse_after: float                          # updated model vs measurements (training data)

    def predict(self, temperatures) -> np.ndarray:
        t = as_2d(temperatures, "temperatures")[:, self.inputs]
        return np.column_stack([cd.predict(t) for cd in self.cds])


def geometric_diagram(support_xyz, support_values, measured_xyz, measured_values, *,
                      w_support: float = 1.0, w_measured: float = 10.0, n_intervals: int = 2,
                      smoothing: float = 1e-3) -> CharacteristicDiagram:
    """Step B of [002 §3.2]: a temporary 3-D CD g(X, Y, Z) through the predicted support-point
    values (weight ``w_support``) and the measured displacements (weight ``w_measured``; 10:1 in
    the paper's Fig. 3 example). The grid spans the support points (the workspace)."""
    sp = as_2d(support_xyz, "support_xyz")
    mp = as_2d(measured_xyz, "measured_xyz")
    if sp.shape[1] != mp.shape[1]:
        raise CharacteristicDiagramError(f"measured_xyz: {mp.shape[1]} coordinates, support_xyz has {sp.shape[1]}")
    u = np.vstack([sp, mp])
    y = np.concatenate([np.ravel(support_values), np.ravel(measured_values)])
    w = np.concatenate([np.full(sp.shape[0], float(w_support)), np.full(mp.shape[0], float(w_measured))])
    both = np.vstack([sp, mp])
    cd = CharacteristicDiagram(n_intervals=n_intervals, smoothing=smoothing,
                               bounds=(both.min(axis=0), both.max(axis=0)))
    return cd.fit(u, y, w)


def measurement_update(temperatures, base_support, support_xyz, measured_xyz, measured, *,
                       inputs: Sequence[int] | None = None, w_support: float = 1.0, w_measured: float = 10.0,
                       geometric_intervals: int = 2, geometric_smoothing: float = 1e-3,
                       make_cd: Callable[[], CharacteristicDiagram] | None = None,
                       augment_noise_k: float = 0.0, augment_copies: int = 0, seed: int = 0) -> MeasurementUpdate:
    """The measurement-based load-case update of [002 §3.2] for one displacement component.

    ``temperatures`` (K samples x P sensors); ``base_support`` (K x J) the base model's relative
    errors at the J support points for each sample (step A); ``measured`` (K x M) the relative
    displacements measured at ``measured_xyz`` (M x 3) - with active compensation, add the
    applied compensation back first (digest gap 4). Step B/C: per sample a geometric CD through
    support predictions and measurements gives adjusted support values; step D: per support
    point an update CD on the temperatures ``inputs`` (default all; choose them with
    :func:`forward_selection` / :func:`stability_selection`) fitted to adjusted - predicted.
    ``augment_copies`` noisy copies of the temperatures (std ``augment_noise_k``) make the
    update robust to run-to-run scatter, as the paper suggests (±1 K in its repeat runs).
    """
    temps = as_2d(temperatures, "temperatures")
    base = as_2d(base_support, "base_support")
    meas = as_2d(measured, "measured")
    sp, mp = as_2d(support_xyz, "support_xyz"), as_2d(measured_xyz, "measured_xyz")
    k = temps.shape[0]
    if base.shape != (k, sp.shape[0]):
        raise CharacteristicDiagramError(f"base_support: shape {base.shape}, expected ({k}, {sp.shape[0]})")
    if meas.shape != (k, mp.shape[0]):
        raise CharacteristicDiagramError(f"measured: shape {meas.shape}, expected ({k}, {mp.shape[0]})")
    cols = list(range(temps.shape[1])) if inputs is None else list(inputs)
    make_cd = make_cd or (lambda: CharacteristicDiagram(n_intervals=2, smoothing=1e-3))
    adjusted = np.empty_like(base)
    for i in range(k):
        g = geometric_diagram(sp, base[i], mp, meas[i], w_support=w_support, w_measured=w_measured,
                              n_intervals=geometric_intervals, smoothing=geometric_smoothing)
        adjusted[i] = g.predict(sp)
    delta = adjusted - base
    t_fit, d_fit = temps[:, cols], delta
    if augment_copies > 0 and augment_noise_k > 0:
        rng = np.random.default_rng(seed)
        t_fit = np.vstack([t_fit] + [t_fit + rng.normal(0, augment_noise_k, t_fit.shape)
                                     for _ in range(augment_copies)])
        d_fit = np.vstack([d_fit] * (augment_copies + 1))
    cds = [make_cd().fit(t_fit, d_fit[:, j]) for j in range(sp.shape[0])]
    update = MeasurementUpdate(cols, cds, adjusted, math.nan, math.nan)
    # quality at the measured points: the support values carried to the measured points by a
    # geometric CD through the support points only (multilinear on a 3x3x3 lattice; the papers
    # interpolate quadratically), base vs updated
    err_b, err_a = [], []
    corr = update.predict(temps)
    for i in range(k):
        gb = geometric_diagram(sp, base[i], mp[:0], meas[i][:0], n_intervals=geometric_intervals,
                               smoothing=geometric_smoothing)
        ga = geometric_diagram(sp, base[i] + corr[i], mp[:0], meas[i][:0], n_intervals=geometric_intervals,
                               smoothing=geometric_smoothing)
        err_b.append(gb.predict(mp) - meas[i])
        err_a.append(ga.predict(mp) - meas[i])
    update.rmse_before = rmse(np.concatenate(err_b), 0.0)
    update.rmse_after = rmse(np.concatenate(err_a), 0.0)
    return update
