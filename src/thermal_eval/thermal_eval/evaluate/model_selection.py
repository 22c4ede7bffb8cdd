"""The contract every evaluated model follows, and its walk-forward inside the training rows.

A model of ``thermal-comp evaluate`` is two functions of the generic
:class:`~thermal_eval.evaluate.spec.EvaluationData`: ``select(data, channel, n_fit)``
chooses inputs and hyper-parameters using rows < ``n_fit`` only, and
``predict(data, channel, params, n_fit)`` fits on rows < ``n_fit`` and returns an open-loop
prediction of every row (temperatures and machine inputs only, never a displacement at or
after ``n_fit``). :func:`out_of_fold_prediction` runs the chosen model on expanding
walk-forward folds inside the training rows: the residuals there measure how fast the
model's error drifts (the adaptive mode's uncertainty), without a row at or after n_train.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from talc_model.open_loop.lagged_temperature_model import walk_forward_folds
from thermal_eval.evaluate.spec import EvaluationData

Select = Callable[[EvaluationData, str, int], dict]
Predict = Callable[[EvaluationData, str, dict, int], np.ndarray]
#: per-input contributions of the open-loop prediction (rows x inputs), fitted on rows < n_fit
Contributions = Callable[[EvaluationData, str, dict, int], np.ndarray]


class ModelFailure(RuntimeError):
    """A model that cannot be used on this recording (unidentifiable, diverged, ...)."""


@dataclass(frozen=True)
class ModelSpec:
    """One evaluated model: name, what it is, its two functions, and whether it needs machine inputs."""

    name: str
    kind: str                       # "baseline" or "model"
    description: str
    select: Select
    predict: Predict
    needs_inputs: bool = False
    #: a linear model's per-input contributions: adaptive mode re-estimates their gains from the
    #: probes (:mod:`talc_model.open_loop.probe_gain_update`); None: the model only gets offsets
    contributions: Contributions | None = None


#: Walk-forward of the adaptive calibration: expanding folds from this fraction of the training rows.
OOF_MIN_FRACTION = 0.5
OOF_FOLDS = 4


def out_of_fold_prediction(model: ModelSpec, data: EvaluationData, channel: str, params: dict,
                           n_train: int) -> tuple[np.ndarray, int]:
    """Prediction of rows [first, n_train) where each block comes from the model fitted on
    every row before it (params fixed); NaN elsewhere. Returns (prediction, first)."""
    out = np.full(len(data), np.nan)
    folds = walk_forward_folds(n_train, OOF_FOLDS, OOF_MIN_FRACTION)
    for fit_end, v0, v1 in folds:
        p = model.predict(data, channel, params, fit_end)
        out[v0:v1] = p[v0:v1]
    return out, folds[0][1]


def checked_prediction(pred: Any, data: EvaluationData, rows: slice, name: str) -> np.ndarray:
    """The prediction as floats, finite on every scored row (a model may not skip rows)."""
    p = np.asarray(pred, dtype=float)
    if p.shape != (len(data),):
        raise ModelFailure(f"{name}: prediction has shape {p.shape}, expected ({len(data)},)")
    bad = ~np.isfinite(p[rows])
    if bad.any():
        raise ModelFailure(f"{name}: prediction not finite on {int(bad.sum())} of the scored rows (diverged)")
    if np.max(np.abs(p[rows])) > 1e6:
        raise ModelFailure(f"{name}: prediction reaches {np.max(np.abs(p[rows])):.3g} um (diverged)")
    return p
