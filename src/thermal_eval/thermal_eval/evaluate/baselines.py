"""The honest baselines of every evaluation table: what a model must beat to be worth using.

- ``train_mean``: the mean displacement of the training rows, constant;
- ``hold_last_training``: the last training displacement held for ever;
- ``static_ls``: least squares of the displacement on the temperatures (no dynamics);
- ``lowpass_ridge``: ridge on the temperatures and one 1-h low-pass copy (penalty chosen by
  walk-forward inside the training rows).

(Beside every adaptive model, holding that model's own probes at exactly its probe instants
is computed by :mod:`thermal_eval.evaluate.adaptive`.) No rclpy here.
"""
from __future__ import annotations

import numpy as np

from talc_model.open_loop.lagged_temperature_model import DEFAULT_ALPHA_GRID, LaggedTemperatureModel, walk_forward_select
from thermal_eval.evaluate.spec import EvaluationData
from thermal_eval.evaluate.model_selection import ModelFailure, ModelSpec

LOWPASS_TAU_S = 3600.0


def _finite_training(data: EvaluationData, channel: str, n_fit: int) -> np.ndarray:
    y = data.displacement_um[channel][:n_fit]
    y = y[np.isfinite(y)]
    if y.size == 0:
        raise ModelFailure(f"{channel}: no finite displacement on the first {n_fit} rows")
    return y


def _mean_predict(data, channel, params, n_fit):
    return np.full(len(data), float(np.mean(_finite_training(data, channel, n_fit))))


def _hold_predict(data, channel, params, n_fit):
    return np.full(len(data), float(_finite_training(data, channel, n_fit)[-1]))


def _static_predict(data, channel, params, n_fit):
    y = data.displacement_um[channel]
    m = LaggedTemperatureModel((), 0.0).fit_recording(data.time_s[:n_fit], data.temperatures[:n_fit], y[:n_fit])
    return m.predict_recording(data.time_s, data.temperatures)


def _lowpass_select(data, channel, n_fit):
    sel = walk_forward_select(data.time_s, data.temperatures, data.displacement_um[channel], n_fit,
                              [(LOWPASS_TAU_S,)], DEFAULT_ALPHA_GRID)
    return {"alpha": sel.alpha, "walk_forward_mae_um": round(sel.best_mae, 3)}


def _lowpass_predict(data, channel, params, n_fit):
    y = data.displacement_um[channel]
    m = LaggedTemperatureModel((LOWPASS_TAU_S,), params["alpha"])
    m.fit_recording(data.time_s[:n_fit], data.temperatures[:n_fit], y[:n_fit])
    return m.predict_recording(data.time_s, data.temperatures)


def _none(data, channel, n_fit):
    return {}


BASELINES = [
    ModelSpec("train_mean", "baseline", "mean of the training displacements", _none, _mean_predict),
    ModelSpec("hold_last_training", "baseline", "last training displacement held", _none, _hold_predict),
    ModelSpec("static_ls", "baseline", "least squares on the temperatures", _none, _static_predict),
    ModelSpec("lowpass_ridge", "baseline", "ridge on temperatures + 1-h low-pass copies", _lowpass_select,
              _lowpass_predict),
]
