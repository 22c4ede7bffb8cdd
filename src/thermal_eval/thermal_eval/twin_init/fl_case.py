"""``bench twin-init``, part (b): FL_THERMAL (a real 46 h spindle recording, MIT licence beside
the data). ``twin init`` on the authors' training rows with descriptions/fl_thermal.yaml; the
twin is then run open loop over the whole recording (its inputs: the speed, the hall t11 and
the coolant return t4) and scored on the test and validation rows (MAE, um) beside the lagged
ridge of ``evaluate`` (walk-forward selected on the training rows), the training mean and a
static regression on the same temperatures, all fitted on the training rows only; then the
twin's soft sensors as an ``evaluate`` model in adaptive mode beside every data-only row
(fl_adaptive.py).
"""
from __future__ import annotations

import pathlib
import time

import numpy as np

from thermal_comp_common.metrics import mae
from thermal_twin.identify import init_twin, load_description
from thermal_twin.identify.scores import static_regression, training_mean

from thermal_eval.evaluate.open_loop_models import lagged_ridge_model
from thermal_eval.fl_thermal.data import Splits, as_evaluation_data, load_fl_thermal
from thermal_eval.twin_init.fl_adaptive import channel_features, comparison, run_rows, soft_sensors

DESCRIPTION = pathlib.Path(__file__).with_name("descriptions") / "fl_thermal.yaml"


def fl_case(out: pathlib.Path, csv: str | None = None, progress=lambda m: None, adaptive: bool = True) -> dict:
    """The init twin's open-loop MAE beside the baselines, and (``adaptive``) its soft sensors'
    ``evaluate`` row beside every data-only adaptive row (fl_adaptive.py)."""
    data = load_fl_thermal(csv)
    rec = data.recording
    s = Splits.authors(len(rec))
    train = rec.slice(0, s.n_train)
    train.source = "FL_THERMAL training rows"
    t0 = time.perf_counter()
    rep = init_twin(load_description(str(DESCRIPTION)), train, out, progress=progress)
    t_init = time.perf_counter() - t0
    X, _, twin = soft_sensors(rep["files"]["twin"], rec)
    ev = as_evaluation_data(data, s)
    ridge = lagged_ridge_model("lagged_ridge", False)
    rows: dict = {}
    for col in twin_errors(rep):
        ch = col.removesuffix("_um")
        y = np.asarray(rec.columns[col], float)
        params = ridge.select(ev, ch, s.n_train)
        preds = {"twin init (open loop)": np.asarray(twin[col], float),
                 "lagged ridge": np.asarray(ridge.predict(ev, ch, params, s.n_train), float)
                 + (y[0] - float(ev.displacement_um[ch][0])),      # the ridge fits deltas from row 0
                 "training mean": training_mean(y, s.n_train),
                 "static regression": static_regression(rec, y, s.n_train)}
        rows[ch] = {name: {"test_mae_um": mae(y[s.test], p[s.test]),
                           "validation_mae_um": mae(y[s.validation], p[s.validation])} for name, p in preds.items()}
    figs = None
    if adaptive:
        t0 = time.perf_counter()
        figs = comparison(run_rows(ev, channel_features(X, twin, ev.channels)))
        figs["wall_s"] = round(time.perf_counter() - t0, 1)
    return {"hidden_bodies": rep["hidden_bodies"], "nodes": rep["nodes"], "rows": rows, "adaptive": figs,
            "init_held_out_rmse": rep["held_out_rmse"], "wall_s": round(t_init, 1),
            "twin_simulated_h_per_s": rep["fit"]["simulated_h_per_s"], "train_rows": s.n_train,
            "test_rows": [s.n_train, s.test_end], "validation_rows": [s.test_end, s.n]}


def twin_errors(rep: dict) -> list[str]:
    return [c for c in rep["held_out_rmse"] if c.endswith("_um")]
