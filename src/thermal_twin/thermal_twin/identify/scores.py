"""Held-out scores of an identified twin beside the baselines a user would try first: the
training mean of each channel, and a static least-squares regression of the channel on the
recording's temperature readings at the same instant (intercept + every temperature column),
both fitted on the same training rows as the twin. RMSE over the held-out rows where the
channel has a value (sparse probes: their rows only). No rclpy.
"""
from __future__ import annotations

import numpy as np

from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording

from thermal_twin.identify.identification import Identification, scored_channels


def training_mean(y: np.ndarray, n_train: int) -> np.ndarray:
    y_tr = y[:n_train]
    return np.full(y.shape, float(np.nanmean(y_tr)) if np.isfinite(y_tr).any() else np.nan)


def static_regression(rec: Recording, y: np.ndarray, n_train: int, exclude: str = "") -> np.ndarray:
    """Least squares of ``y`` on every temperature column (but ``exclude``) and an intercept,
    on the training rows where all are finite; NaN where a temperature is missing."""
    names = [c for c in rec.sensors if c != exclude]
    X = np.column_stack([np.ones(len(rec))] + [np.asarray(rec.columns[c], float) for c in names])
    ok = np.isfinite(X).all(axis=1) & np.isfinite(y)
    ok[n_train:] = False
    if ok.sum() <= X.shape[1]:
        return np.full(y.shape, np.nan)
    coef, *_ = np.linalg.lstsq(X[ok], y[ok], rcond=None)
    return X @ coef


def held_out_table(ident: Identification, rec: Recording) -> dict[str, dict[str, float]]:
    """channel -> {twin, training mean, static regression, n}: held-out RMSE of the chosen
    structure fitted on the training rows only, and of the baselines on the same rows."""
    k = ident.n_train
    cal = ident.chosen.calibration
    out = {}
    for c in scored_channels(ident.description, ident.channels):
        y = np.asarray(rec.columns[c], float)
        row = {"twin": rmse(y[k:], np.asarray(cal.after[c])[k:]),
               "twin before fit": rmse(y[k:], np.asarray(cal.before[c])[k:]),
               "training mean": rmse(y[k:], training_mean(y, k)[k:]),
               "static regression": rmse(y[k:], static_regression(rec, y, k, exclude=c)[k:]),
               "n": int(np.isfinite(y[k:]).sum())}
        out[c] = row
    return out
