"""Open-loop ARX on FL_THERMAL: the generic ``arx_simulation`` model on the benchmark's data.

The model (TALC's ARX on the 5-min grid, medoid sensors of k-means groups, orders by MDL on a
chronological 60/40 split of the fit rows, simulated after them; optionally evaluated between
grid samples) is :mod:`thermal_eval.open_loop_models` (``arx_model``, ``subgrid_prediction``),
the same one ``thermal-comp evaluate`` runs. This module only adapts the benchmark's
:class:`FlThermalData` and :class:`Splits` to it and keeps the benchmark's result shape
(NaN on the fit rows: no prediction is claimed there). No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from thermal_eval.fl_thermal_data import FlThermalData, FlThermalError, Splits, as_evaluation_data
from thermal_eval.model_selection import ModelFailure
from thermal_eval.open_loop_models import GRID_STEP_S, GROUP_CANDIDATES, arx_model  # noqa: F401 (re-exported)


@dataclass
class ArxChannel:
    prediction: np.ndarray                # every row; NaN on the training rows
    inputs: list[str]
    na: int
    nb: list[int]
    validation_rms_um: float              # simulation mode, last 40 % of the training grid
    candidates: dict[str, float | str]    # input set -> validation RMS (or why it failed)
    prediction_subgrid: np.ndarray | None = None   # evaluated between grid samples


def arx_open_loop_channel(data: FlThermalData, splits: Splits, channel: str,
                          group_candidates: Sequence[int] = GROUP_CANDIDATES,
                          with_spindle: bool = False) -> ArxChannel:
    """Choose inputs and orders on rows < ``splits.n_train``, then simulate over the rest
    (grid-held and sub-grid). ``with_spindle``: the spindle speed (krpm) is one more input."""
    ed = as_evaluation_data(data, splits)
    n = splits.n_train
    held, sub = arx_model("arx", with_spindle, False, group_candidates), arx_model("arx", with_spindle, True,
                                                                                  group_candidates)
    try:
        params = held.select(ed, channel, n)
        pred, pred_sub = held.predict(ed, channel, params, n), sub.predict(ed, channel, params, n)
    except ModelFailure as exc:
        raise FlThermalError(f"{channel}: {exc}") from None
    pred, pred_sub = pred.copy(), pred_sub.copy()
    pred[:n] = np.nan
    pred_sub[:n] = np.nan
    return ArxChannel(pred, list(params["inputs"]) + (["spindle_krpm"] if with_spindle else []), params["na"],
                      params["nb"], params["training_validation_rms_um"], params["input_sets"], pred_sub)
