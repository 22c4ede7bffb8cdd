"""Open-loop ARX on FL_THERMAL: TALC's model class, trained once, run in simulation mode.

Per channel a MISO ARX model (:mod:`talc_model.arx`) on the thesis's 5-min grid
(``GRID_STEP_S``, every 20th row of 15 s), inputs = temperature deltas of a few representative
sensors. Everything is chosen on the training rows only:

- input sets: one medoid sensor per k-means group of the training-row temperatures
  (:func:`talc_model.sensor_selection.sensor_medoids`), for each k in ``GROUP_CANDIDATES``;
- orders (n_a in ``NA_RANGE``, n_b in ``NB_RANGE``) by MDL on a chronological 60/40 split of
  the training grid (:func:`order_selection.select_orders`, simulation-mode validation);
- per channel the k whose chosen model has the lowest simulation-mode RMS on that 40 %.

The model is refitted on all training grid rows and then *simulated*: from the end of the
training rows on, its own predictions are fed back as the autoregressive outputs (the initial
state is the last n_a training displacements), driven by the temperatures only; no
displacement after row n_train - 1 is used. A 15-s row gets the value of the grid sample at or
before it (causal hold; the first < 20 test rows therefore hold the last training grid value).
``arx_simulation_spindle`` adds the spindle speed as one more input (reported separately).

``ArxChannel.prediction_subgrid`` evaluates the same simulation between grid samples instead of
holding: a row r after grid sample k gets y_k + f (y~_{k+1}(r) - y_k), f = (t_r - t_k) / step,
where y~_{k+1}(r) is the model's next grid value computed with the inputs of row r in place of
those of grid sample k+1 (only the b_0 terms change; outputs and older inputs are the grid's).
It uses nothing later than row r, and removes most of the 5-min hold error of a fast-moving
displacement (FL_THERMAL ch3/ch4 move ~0.6 um within 5 min after a spindle step).
No rclpy here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from talc_model.arx import RankDeficientError
from talc_model.order_selection import select_orders
from talc_model.sensor_selection import sensor_medoids
from thermal_eval.fl_thermal_adaptive import TALC_GROUP_CANDIDATES
from thermal_eval.fl_thermal_data import SENSORS, FlThermalData, FlThermalError, Splits

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
    prediction_subgrid: np.ndarray | None = None   # evaluated between grid samples (module docstring)


def subgrid_prediction(model, u_rows: np.ndarray, grid: np.ndarray, pred_grid: np.ndarray, first: int) -> np.ndarray:
    """Rows from grid index ``first`` on, evaluated between the grid samples (module docstring).

    ``u_rows``: inputs at every row (N x m); ``grid``: row index of each grid sample;
    ``pred_grid``: outputs on the grid (measured before ``first``, simulated after).
    """
    n = u_rows.shape[0]
    step = int(grid[1] - grid[0]) if grid.size > 1 else 1
    o = model.orders
    out = np.full(n, np.nan)
    u_grid = u_rows[grid]
    g_rows = np.arange(n) // step                  # grid index at or before each row
    rows = np.arange(grid[first], n)
    k = g_rows[rows]
    out[rows] = pred_grid[k]                        # grid rows (and the fallback for nk > 0)
    if o.nk != 0:
        return out
    nxt = k + 1                                     # the grid sample being approached
    val = np.full(rows.size, model.c)
    for i in range(1, o.na + 1):
        val -= model.a[i - 1] * pred_grid[nxt - i]
    for j, bj in enumerate(model.b):
        for lag in range(1, bj.size):
            val += bj[lag] * u_grid[nxt - lag, j]
        if bj.size:
            val += bj[0] * u_rows[rows, j]
    frac = (rows - grid[k]) / float(step)
    inside = frac > 0
    out[rows[inside]] = pred_grid[k[inside]] + frac[inside] * (val[inside] - pred_grid[k[inside]])
    return out


def arx_open_loop_channel(data: FlThermalData, splits: Splits, channel: str,
                          group_candidates: Sequence[int] = GROUP_CANDIDATES,
                          input_sets: dict[int, list[str]] | None = None, with_spindle: bool = False) -> ArxChannel:
    """Choose inputs and orders on the training rows, then simulate over the test and validation rows.

    ``with_spindle``: the spindle speed (krpm) is one more input of every candidate set.
    """
    n = len(data)
    step = max(1, int(round(GRID_STEP_S / float(np.median(np.diff(data.time_s))))))
    grid = np.arange(0, n, step)
    n_train_grid = int(np.sum(grid < splits.n_train))
    if n_train_grid < 20:
        raise FlThermalError(f"rows: {splits.n_train} training rows give {n_train_grid} grid samples, need >= 20")
    y = data.displacement_um[channel][grid]
    sets = input_sets or {k: sensor_medoids(data.temperatures[:splits.n_train], int(k), SENSORS) for k in group_candidates}
    best = None
    scores: dict[str, float] = {}
    for k, names in sets.items():
        cols = [SENSORS.index(s) for s in names]
        u_rows = data.temperatures[:, cols] - data.temperatures[0, cols]
        if with_spindle:
            u_rows = np.column_stack([u_rows, data.spindle_rpm / 1000.0])
        u = u_rows[grid]
        try:
            sel = select_orders(y[:n_train_grid], u[:n_train_grid], NA_RANGE, NB_RANGE, criterion="mdl",
                                train_fraction=0.6)
        except RankDeficientError:
            continue
        scores[",".join(names)] = round(float(sel.validation_rms), 3)
        if best is None or sel.validation_rms < best[0]:
            best = (float(sel.validation_rms), names, u, sel, u_rows)
    if best is None:
        raise FlThermalError(f"{channel}: no input set gives an identifiable ARX model on the training rows")
    rms, names, u, sel, u_rows = best
    model = sel.model
    pred_grid = model.simulate(u, y[:n_train_grid], n_train_grid)   # outputs after training never used
    pred_grid[:n_train_grid] = y[:n_train_grid]   # the state the simulation starts from (training data)
    pred = pred_grid[np.arange(n) // step]
    pred[:splits.n_train] = np.nan                  # no prediction is claimed on the training rows
    # sub-grid evaluation from the last training grid sample on (rows before n_train stay NaN)
    sub = subgrid_prediction(model, u_rows, grid, pred_grid, n_train_grid - 1)
    sub[:splits.n_train] = np.nan
    return ArxChannel(pred, list(names) + (["spindle_krpm"] if with_spindle else []), int(sel.orders.na),
                      [int(b) for b in sel.orders.nb], rms, scores, sub)
