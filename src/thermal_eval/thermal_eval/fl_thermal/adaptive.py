"""Adaptive models on FL_THERMAL replayed from row 0: TALC and AGP with one probing every 2 h after calibration.

The models calibrated on the training rows (``talc_calibrated*``, ``agp_calibrated``) are
closed-loop rows of ``thermal-comp evaluate`` (:mod:`thermal_eval.evaluate.model_rows`); the
benchmark runs them through it (:func:`thermal_eval.fl_thermal.benchmark.run_generic_adaptive`).

``talc_own_cp``, ``agp`` and ``agp_load_probing`` (plus dense probing after every
spindle-speed change, :mod:`talc_model.probing.load_driven`; reported separately) replay the whole recording from row 0 (:func:`virtual_experiment.run_virtual_experiment`)
and see a displacement only when their own schedule probes: TALC in its calibration phase
(every 5 min + 95 s), then every 2 h (``post_cp_interval_h = 2``) and in its no-good phases
(12 probes every 10 min); the AGP in its calibration phase (every 6 min, >= 4 h), then every
2 h as a control measurement (``control_interval_s = 7200``) and whenever its predictive std
exceeds sigma_max (recalibration). Q_prod charges 95 s per probing.

Configuration, fixed without the test rows:

- ``talc_own_cp`` (TALC from row 0) identifies ARX models whose calibration phase needs sum-of-orders measurements, so 16
  correlated temperatures (16 x 10 input lags) are not practical; its inputs are the medoid
  sensors of k-means groups of the *training-row temperatures* (z-scored series, as the AGP
  groups sensors), and the number of groups is chosen from ``TALC_GROUP_CANDIDATES`` by
  replaying TALC over the training rows only and scoring, like the open-loop walk-forward,
  the mean MAE over channels on the second half of the training rows. Everything a TALC
  prediction is scored on was predicted before the probe that measured it.
- AGP: all 16 temperatures (ARD length scales weigh them); expected maximum error (sigma_max is
  10 % of it) = the largest |displacement| of the training rows, rounded up to 10 um.

No rclpy here.
"""
from __future__ import annotations

import math
import time
from typing import Any, Mapping, Sequence

import numpy as np
from tqdm import tqdm
from talc_model.adaptive_model import make_model
from talc_model.probing.load_driven import LoadDrivenProbing
from talc_model.open_loop.sensor_selection import sensor_medoids

from thermal_eval.fl_thermal.data import (CHANNELS, SENSORS, SPINDLE_COLUMN, FlThermalData, FlThermalError, Splits,
                                          as_evaluation_data, mae)
from thermal_eval.evaluate.model_rows import hold_probes, replay
from thermal_eval.evaluate.open_loop_models import GROUP_CANDIDATES
from thermal_eval.replay.virtual_experiment import ReplayColumns, run_virtual_experiment

#: One probing every 2 h after calibration (the benchmark's protocol); 95 s per probing for Q_prod.
PROBE_INTERVAL_S = 7200.0
PROBE_DURATION_S = 95.0
#: Numbers of sensor groups tried for TALC's inputs (one medoid sensor per group): the generic ARX's.
TALC_GROUP_CANDIDATES = GROUP_CANDIDATES


def _columns():
    return ReplayColumns(sensors={s: f"{s}_c" for s in SENSORS}, inputs={SPINDLE_COLUMN: SPINDLE_COLUMN},
                         errors={c: f"{c}_um" for c in CHANNELS})


def talc_config(inputs: Sequence[str]) -> dict[str, Any]:
    return {"component_names": list(CHANNELS), "angular_components": [], "input_names": list(inputs),
            "post_cp_interval_h": PROBE_INTERVAL_S / 3600.0, "probe_duration_s": PROBE_DURATION_S}


def select_talc_inputs(data: FlThermalData, splits: Splits, candidates: Sequence[int] = TALC_GROUP_CANDIDATES,
                       overrides: Mapping[str, Any] | None = None, show_progress: bool = True
                       ) -> tuple[list[str], dict[str, float]]:
    """TALC inputs chosen on the training rows only (see the module docstring)."""
    n = splits.n_train
    train_T = data.temperatures[:n]
    scores: dict[str, float] = {}
    best: tuple[float, list[str]] = (math.inf, [])
    for k in tqdm(list(candidates), desc="TALC inputs (training rows)", disable=not show_progress, leave=False):
        inputs = sensor_medoids(train_T, int(k), SENSORS)
        cfg = {**talc_config(inputs), **dict(overrides or {})}
        res = run_virtual_experiment(data.recording, make_model("talc", cfg), columns=_columns(),
                                     probed_components=list(CHANNELS), stop=n, compute_metrics=False)
        half = slice(n // 2, n)
        score = float(np.mean([mae(data.displacement_um[c][half],
                                   np.where(np.isfinite(res.predicted[c]), res.predicted[c], 0.0)[half])
                               for c in CHANNELS]))
        scores[f"k={k}:" + ",".join(inputs)] = round(score, 3)
        if score < best[0]:
            best = (score, inputs)
    if not best[1]:
        raise FlThermalError(f"TALC input candidates {list(candidates)!r}: none could be scored")
    return best[1], scores


def adaptive_configs(data: FlThermalData, splits: Splits, talc_inputs: Sequence[str],
                     agp_load_probing: bool = False) -> dict[str, tuple[str, dict]]:
    """name -> (kind, config) of the replayed adaptive models (``agp_load_probing``: also the AGP
    with dense probing after load changes; each extra probing may re-optimise the GP, which makes
    that replay take many minutes)."""
    max_err = max(float(np.max(np.abs(data.displacement_um[c][:splits.n_train]))) for c in CHANNELS)
    max_err = 10.0 * math.ceil(max(max_err, 1e-9) / 10.0)
    agp = {"components": list(CHANNELS), "sensors": list(SENSORS), "control_interval_s": PROBE_INTERVAL_S,
           "probe_duration_s": PROBE_DURATION_S, "max_expected_error_um": max_err}
    configs = {"talc_own_cp": ("talc", talc_config(talc_inputs)), "agp": ("agp", agp)}
    if agp_load_probing:
        configs["agp_load_probing"] = ("agp", dict(agp))
    return configs


#: replayed models whose schedule also probes densely after every spindle-speed change
#: (:class:`talc_model.probing.load_driven.LoadDrivenProbing`, same phase as TALC's NG phase)
LOAD_PROBING_REPLAYS = ("agp_load_probing",)


def run_adaptive(data: FlThermalData, splits: Splits, configs: Mapping[str, tuple[str, dict]],
                 show_progress: bool = True) -> tuple[dict, dict[str, dict[str, np.ndarray]], dict[str, list[int]]]:
    """Replay the whole recording through each adaptive model (the generic replay loop,
    :func:`thermal_eval.evaluate.model_rows.replay`); MAE of the compensation per split."""
    ed = as_evaluation_data(data, splits)
    figures: dict[str, Any] = {}
    predictions: dict[str, dict[str, np.ndarray]] = {}
    probe_rows: dict[str, list[int]] = {}
    for name, (kind, cfg) in configs.items():
        model = make_model(kind, cfg)
        if name in LOAD_PROBING_REPLAYS:
            model = LoadDrivenProbing(model, load_key=SPINDLE_COLUMN, probe_duration_s=PROBE_DURATION_S)
        t0 = time.perf_counter()
        run = replay(ed, model, show_progress=show_progress)
        res = run.result
        wall = time.perf_counter() - t0
        fig: dict[str, Any] = {}
        predictions[name] = run.compensation
        probes = np.asarray(res.probe_times_s)
        probe_rows[name] = run.probe_rows
        for ch in CHANNELS:
            comp, true = run.compensation[ch], data.displacement_um[ch]
            held = np.nan_to_num(hold_probes(true, probe_rows[name], len(data)))   # hold its own probes
            fig[ch] = {"mae_um": round(mae(true[splits.test], comp[splits.test]), 3),
                       "mae_validation_um": round(mae(true[splits.validation], comp[splits.validation]), 3),
                       "hold_last_measurement_mae_um": round(mae(true[splits.test], held[splits.test]), 3),
                       "hold_last_measurement_mae_validation_um": round(mae(true[splits.validation],
                                                                            held[splits.validation]), 3)}
        fig["q_prod_pct"] = round(float(res.final_status["q_prod_pct"]), 2)
        fig["probing_cycles"] = int(probes.size)
        fig["probing_cycles_test_rows"] = int(np.sum((probes >= data.time_s[splits.n_train]) &
                                                    (probes < data.time_s[splits.test_end])))
        after_cal = np.flatnonzero(np.asarray(res.phase) != "calibration")
        fig["calibration_end_h"] = round(float(data.time_s[after_cal[0]] / 3600.0), 2) if after_cal.size else None
        fig["no_good_phases"] = int(res.final_status.get("no_good_phases", 0))
        fig["parameter_updates"] = int(res.final_status.get("parameter_updates", 0))
        fig["replay_s"] = round(wall, 1)
        fig["load_change_phases"] = int(getattr(model, "load_phases", 0))
        figures[name] = fig
    return figures, predictions, probe_rows
