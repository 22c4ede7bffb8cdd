"""Scores on held-out probes, the only truth a real cell has. Every predictor is asked for the
error at a probe instant BEFORE that probe is seen (prequential), and then learns from it as it
would online. Beside the adaptive model (started from a prior) stand the honest baselines at the
same instants: holding the last probe, the training probes' mean, and a static least-squares
regression of the training probes on the temperatures. No rclpy.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from thermal_comp_common import metrics
from thermal_comp_common.recording_csv import Recording
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.replay.virtual_experiment import ReplayColumns


def prequential_model(model, rec: Recording, probes: ProbeSet) -> dict[str, np.ndarray]:
    """The model's prediction at every probe instant before it learns that probe; it runs over
    every row of ``rec`` (inputs at every instant, probes only at theirs)."""
    cols = ReplayColumns.from_recording(rec)
    names = [c for c in model.component_names if c in probes.values]
    at = {round(float(t), 3): i for i, t in enumerate(probes.time_s)}
    out = {c: np.full(probes.time_s.size, np.nan) for c in names}
    sens = {s: np.asarray(rec.columns[c], float) for s, c in cols.sensors.items()}
    inps = {s: np.asarray(rec.columns[c], float) for s, c in cols.inputs.items()}
    for k, t in enumerate(rec.time_s):
        t = float(t)
        model.update_inputs(t, {s: float(v[k]) for s, v in sens.items()}, {s: float(v[k]) for s, v in inps.items()})
        i = at.get(round(t, 3))
        if i is None:
            continue
        pred, _ = model.predict(t)
        p = {c: float(pred.get(c, math.nan)) for c in names}
        meas = {c: float(probes.values[c][i]) for c in names if math.isfinite(probes.values[c][i])}
        for c in names:
            out[c][i] = p[c]
        if meas:
            applied = {c: (p[c] if math.isfinite(p[c]) else 0.0) for c in meas}
            model.add_measurement(t, {c: meas[c] - applied[c] for c in meas}, applied)
    return out


def hold_last(probes: ProbeSet) -> dict[str, np.ndarray]:
    """At each probe, the value of the probe before it (NaN for the first)."""
    out = {}
    for c, v in probes.values.items():
        held = np.full(v.size, np.nan)
        last = math.nan
        for i, x in enumerate(v):
            held[i] = last
            if math.isfinite(x):
                last = x
        out[c] = held
    return out


def training_mean(probes: ProbeSet, train_until_s: float) -> dict[str, np.ndarray]:
    train = probes.time_s <= train_until_s
    return {c: np.full(v.size, np.nanmean(v[train]) if np.isfinite(v[train]).any() else np.nan)
            for c, v in probes.values.items()}


def static_regression(rec: Recording, probes: ProbeSet, train_until_s: float) -> dict[str, np.ndarray]:
    """Least squares of the training probes on the temperatures (deltas from the first row) at
    the probe instants, with an intercept; temperature columns with a gap at a probe are left out."""
    idx = np.searchsorted(rec.time_s, probes.time_s)
    temps = [np.asarray(rec.columns[c], float) for c in rec.names("sensor")]
    x = np.column_stack([t[idx] - t[0] for t in temps if np.isfinite(t[idx]).all() and math.isfinite(t[0])]
                        + [np.ones(idx.size)])
    train = probes.time_s <= train_until_s
    out = {}
    for c, v in probes.values.items():
        ok = train & np.isfinite(v)
        if ok.sum() < x.shape[1] + 2:           # fewer probes than parameters: a ridge would be a guess
            out[c] = np.full(v.size, np.nan)
            continue
        beta, *_ = np.linalg.lstsq(x[ok], v[ok], rcond=None)
        out[c] = x @ beta
    return out


def score_table(probes: ProbeSet, predictors: Mapping[str, Mapping[str, np.ndarray]],
                held_out: np.ndarray) -> dict[str, Any]:
    """RMSE, MAE and P99 of |probe - prediction| per predictor and component on the held-out
    probes (the probe noise is part of every figure alike)."""
    table: dict[str, Any] = {}
    for name, pred in predictors.items():
        row = {}
        for c, v in probes.values.items():
            p = np.asarray(pred.get(c, np.full(v.size, np.nan)), float)
            ok = held_out & np.isfinite(v) & np.isfinite(p)
            if not ok.any():
                row[c] = {"rmse": math.nan, "mae": math.nan, "p99": math.nan, "n": 0}
                continue
            r = v[ok] - p[ok]
            row[c] = {"rmse": metrics.rmse(v[ok], p[ok]), "mae": float(np.mean(np.abs(r))),
                      "p99": float(np.percentile(np.abs(r), 99)), "n": int(ok.sum())}
        table[name] = row
    return table
