"""Open-loop ARX on FL_THERMAL: TALC's model class, trained once, run in simulation mode.

Per channel a MISO ARX model (:mod:`talc_model.arx`) on the thesis's 5-min grid
(``GRID_STEP_S``, every 20th row of 15 s), inputs = temperature deltas of a few representative
sensors. Everything is chosen on the training rows only:

- input sets: one medoid sensor per k-means group of the training-row temperatures
  (:func:`fl_thermal_adaptive.sensor_medoids`), for each k in ``GROUP_CANDIDATES``;
- orders (n_a in ``NA_RANGE``, n_b in ``NB_RANGE``) by MDL on a chronological 60/40 split of
  the training grid (:func:`order_selection.select_orders`, simulation-mode validation);
- per channel the k whose chosen model has the lowest simulation-mode RMS on that 40 %.

The model is refitted on all training grid rows and then *simulated*: from the end of the
training rows on, its own predictions are fed back as the autoregressive outputs (the initial
state is the last n_a training displacements), driven by the temperatures only; no
displacement after row n_train - 1 is used. A 15-s row gets the value of the grid sample at or
before it (causal hold; the first < 20 test rows therefore hold the last training grid value).
``arx_simulation_spindle`` adds the spindle speed as one more input (reported separately).
No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from talc_model.fl_thermal_adaptive import TALC_GROUP_CANDIDATES, sensor_medoids
from talc_model.fl_thermal_data import SENSORS, FlThermalData, FlThermalError, Splits

GRID_STEP_S = 300.0                       # the TALC model grid (5 min = 20 rows of 15 s)
NA_RANGE = (1, 2)
NB_RANGE = (1, 6)                         # up to 30 min of input history per sensor
GROUP_CANDIDATES = TALC_GROUP_CANDIDATES


@dataclass
class ArxChannel:
    prediction: np.ndarray                # every row; NaN on the training rows
    inputs: list[str]
    na: int
    nb: list[int]
    validation_rms_um: float              # simulation mode, last 40 % of the training grid
    candidates: dict[str, float]          # input set -> validation RMS


def arx_open_loop_channel(data: FlThermalData, splits: Splits, channel: str,
                          group_candidates: Sequence[int] = GROUP_CANDIDATES,
                          input_sets: dict[int, list[str]] | None = None, with_spindle: bool = False) -> ArxChannel:
    """Choose inputs and orders on the training rows, then simulate over the test and validation rows.

    ``with_spindle``: the spindle speed (krpm) is one more input of every candidate set.
    """
    from talc_model.arx import RankDeficientError
    from talc_model.order_selection import select_orders
    n = len(data)
    step = max(1, int(round(GRID_STEP_S / float(np.median(np.diff(data.time_s))))))
    grid = np.arange(0, n, step)
    n_train_grid = int(np.sum(grid < splits.n_train))
    if n_train_grid < 20:
        raise FlThermalError(f"rows: {splits.n_train} training rows give {n_train_grid} grid samples, need >= 20")
    y = data.displacement_um[channel][grid]
    sets = input_sets or {k: sensor_medoids(data.temperatures[:splits.n_train], int(k)) for k in group_candidates}
    best = None
    scores: dict[str, float] = {}
    for k, names in sets.items():
        cols = [SENSORS.index(s) for s in names]
        u = (data.temperatures[:, cols] - data.temperatures[0, cols])[grid]
        if with_spindle:
            u = np.column_stack([u, (data.spindle_rpm / 1000.0)[grid]])
        try:
            sel = select_orders(y[:n_train_grid], u[:n_train_grid], NA_RANGE, NB_RANGE, criterion="mdl",
                                train_fraction=0.6)
        except RankDeficientError:
            continue
        scores[",".join(names)] = round(float(sel.validation_rms), 3)
        if best is None or sel.validation_rms < best[0]:
            best = (float(sel.validation_rms), names, u, sel)
    if best is None:
        raise FlThermalError(f"{channel}: no input set gives an identifiable ARX model on the training rows")
    rms, names, u, sel = best
    model = sel.model
    pred_grid = model.simulate(u, y[:n_train_grid], n_train_grid)   # outputs after training never used
    pred_grid[:n_train_grid] = y[:n_train_grid]   # the state the simulation starts from (training data)
    pred = pred_grid[np.arange(n) // step]
    pred[:splits.n_train] = np.nan                  # no prediction is claimed on the training rows
    return ArxChannel(pred, list(names) + (["spindle_krpm"] if with_spindle else []), int(sel.orders.na), [int(b) for b in sel.orders.nb], rms, scores)
