"""TALC on FL_THERMAL with the training rows as its calibration phase, then one probing every 2 h.

Model: TALC's ARX model class on the 5-min grid (:mod:`thermal_eval.fl_thermal_arx`: inputs = medoid
sensors of k-means groups, orders by MDL, chosen on the calibration rows), identified on the
calibration rows 0..n_train-1 (the authors' protocol gives a model every training displacement;
a real calibration phase would probe at every 5-min grid sample of those 27.8 h, and Q_prod
charges exactly those probings). After calibration the ARX runs in simulation mode on the
temperatures (read between its grid samples with the current inputs, ``subgrid``, or held,
``grid_hold``), and every probing updates the model's state through the slow-error Kalman filter
of :mod:`talc_model.probe_update` / :mod:`talc_model.slow_error_filter`: its noise ratio r lets a probe count less than
fully when fast transients dominate what one probe catches, r = 0 is TALC's "measurement
replaces prediction" (on FL_THERMAL the walk-forward chose r = 0 on every channel), and the
estimated offset decays with the time constant tau. A residual beyond the action-control
limit (ACL) starts a no-good phase of 12 probes every 10 min. The ARX parameters are not re-estimated after calibration: a 2-h probe adds one
sample to the ~330 of the calibration grid.

Hyper-parameters, chosen WITHOUT rows >= n_train (walk-forward inside the training rows): for
each fold start k in ``FOLD_STARTS`` (fractions of the training rows) the whole procedure is
repeated with rows 0..k-1 as calibration (input sets, orders, ARX fit) and rows k..n_train-1
replayed with 2-h probes and the ACL; per channel the (evaluation, tau, r) triple with the
lowest mean MAE over the folds is taken. The ACL is a user setting, not tuned:
``acl_um = 5`` is the thesis's value for a 5-axis machine, 1 um the setting a 1-um target asks
for; each ACL is reported with its own Q_prod. The load-driven variant (``load_probing``) also
starts a dense-probing phase at every spindle-speed change (known to the CNC): the model is
least sure right after a load change; reported separately, with its own Q_prod.

No rclpy here.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from talc_model.probe_update import ProbeSchedule, q_prod_pct, run_probe_updates
from talc_model.slow_error_filter import SlowErrorFilter
from thermal_eval.closed_loop_rows import hold_probes
from thermal_eval.fl_thermal_arx import GROUP_CANDIDATES as ARX_GROUP_CANDIDATES
from thermal_eval.fl_thermal_data import CHANNELS, FlThermalData, FlThermalError, Splits, mae, walk_forward_fold_rows

#: Slow-error time constants tried (s): 30 min (spindle nose) ... 24 h (a drifting reference).
BIAS_TAU_GRID_S = (1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 86400.0)
#: Fast / slow model-error variance ratios tried (0 = the probe is the slow error exactly).
NOISE_RATIO_GRID = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0)
#: How the 5-min ARX is read between its grid samples (see :func:`calibrated_arx`).
EVALUATIONS = ("grid_hold", "subgrid")
#: Walk-forward fold starts as fractions of the training rows (calibrate before, replay after).
FOLD_STARTS = (0.6, 0.7, 0.8)
#: Sensor-group counts for the ARX inputs (one medoid each), those of the open-loop ARX.
GROUP_CANDIDATES = ARX_GROUP_CANDIDATES


@dataclass
class CalibratedTalc:
    prediction: dict[str, np.ndarray]     # open-loop ARX after calibration (NaN on calibration rows)
    compensation: dict[str, np.ndarray]   # with the probe state updates
    probe_rows: list[int]
    no_good_phases: int
    calibration_probings: int             # 5-min grid samples of the calibration rows
    schedule: ProbeSchedule
    filters: dict[str, SlowErrorFilter]
    evaluation: dict[str, str]            # "grid_hold" or "subgrid" per channel
    walk_forward_mae_um: dict[str, float]
    walk_forward_scores: dict[str, dict[str, float]]
    inputs: dict[str, list[str]]
    load_change_phases: int = 0           # dense-probing phases started by a spindle-speed change


def load_change_rows(data: FlThermalData) -> list[int]:
    """Rows where the commanded spindle speed differs from the row before (known to the CNC)."""
    rpm = data.spindle_rpm
    return [int(r) for r in np.flatnonzero(np.diff(rpm) != 0) + 1]


def grid_step_rows(data: FlThermalData) -> int:
    from thermal_eval.open_loop_models import GRID_STEP_S
    return max(1, int(round(GRID_STEP_S / float(np.median(np.diff(data.time_s))))))


def calibrated_arx(data: FlThermalData, n_calibration: int, channel: str, group_candidates: Sequence[int],
                   with_spindle: bool, cache: dict | None = None) -> tuple[dict[str, np.ndarray], list[str]]:
    """ARX identified on rows < n_calibration only (inputs, orders, parameters), simulated after:
    ({evaluation mode: prediction for every row, NaN before n_calibration}, input names).
    Modes (:data:`EVALUATIONS`): "grid_hold" holds each 5-min grid value, "subgrid" evaluates
    between grid samples (:func:`open_loop_models.subgrid_prediction`)."""
    from thermal_eval.fl_thermal_arx import arx_open_loop_channel
    key = (channel, int(n_calibration), bool(with_spindle), tuple(group_candidates))
    if cache is not None and key in cache:
        return cache[key]
    splits = Splits(n_calibration, n_calibration + 1, len(data))
    r = arx_open_loop_channel(data, splits, channel, group_candidates, with_spindle=with_spindle)
    out = ({"grid_hold": r.prediction, "subgrid": r.prediction_subgrid}, list(r.inputs))
    if cache is not None:
        cache[key] = out
    return out


def last_calibration_probe_s(data: FlThermalData, n_calibration: int) -> float:
    """Time of the last grid sample (= calibration probing) before row ``n_calibration``."""
    step = grid_step_rows(data)
    return float(data.time_s[((n_calibration - 1) // step) * step])


def walk_forward_filter(data: FlThermalData, splits: Splits, channel: str, schedule: ProbeSchedule, *,
                        group_candidates: Sequence[int] = GROUP_CANDIDATES, with_spindle: bool = False,
                        fold_starts: Sequence[float] = FOLD_STARTS, tau_grid: Sequence[float] = BIAS_TAU_GRID_S,
                        ratio_grid: Sequence[float] = NOISE_RATIO_GRID, evaluations: Sequence[str] = EVALUATIONS,
                        load_probing: bool = False, arx_cache: dict | None = None
                        ) -> tuple[str, SlowErrorFilter, float, dict[str, float]]:
    """The channel's (evaluation mode, slow-error filter) chosen by the walk-forward replay inside
    rows < n_train (the channel replayed alone, its own residual deciding the no-good phases)."""
    unknown = sorted(set(evaluations) - set(EVALUATIONS))
    if unknown or not evaluations:
        raise FlThermalError(f"evaluations: {list(evaluations)!r} must be a non-empty subset of {list(EVALUATIONS)}")
    n = splits.n_train
    y = data.displacement_um[channel]
    folds = []
    for k in walk_forward_fold_rows(fold_starts, n):
        folds.append((k, calibrated_arx(data, k, channel, group_candidates, with_spindle, arx_cache)[0]))
    changes = load_change_rows(data) if load_probing else []
    scores: dict[str, float] = {}
    best: tuple[float, str, SlowErrorFilter | None] = (math.inf, "", None)
    for mode, tau, ratio in itertools.product(evaluations, tau_grid, ratio_grid):
        flt = SlowErrorFilter(float(tau), float(ratio))
        errs = []
        for k, preds in folds:
            r = run_probe_updates(data.time_s, y, preds[mode], k, schedule, [flt], stop=n,
                                  last_calibration_probe_s=last_calibration_probe_s(data, k),
                                  load_change_rows=changes)
            errs.append(mae(y[k:n], r.compensation[k:n, 0]))
        score = float(np.mean(errs))
        scores[f"{mode},tau={tau / 3600.0:g}h,ratio={ratio:g}"] = round(score, 3)
        if score < best[0]:
            best = (score, mode, flt)
    if best[2] is None:
        raise FlThermalError(f"{channel}: no walk-forward fold could be scored")
    return best[1], best[2], best[0], scores


def run_calibrated_talc(data: FlThermalData, splits: Splits, schedule: ProbeSchedule, *,
                        with_spindle: bool = False, group_candidates: Sequence[int] = GROUP_CANDIDATES,
                        fold_starts: Sequence[float] = FOLD_STARTS, tau_grid: Sequence[float] = BIAS_TAU_GRID_S,
                        ratio_grid: Sequence[float] = NOISE_RATIO_GRID, evaluations: Sequence[str] = EVALUATIONS,
                        load_probing: bool = False, arx_cache: dict | None = None, progress=None) -> CalibratedTalc:
    """Choose each channel's filter on the training rows, calibrate on all of them, then replay
    the rows after with one probing of all five channels every 2 h (and no-good phases)."""
    modes, filters, wf, scores, preds, inputs = {}, {}, {}, {}, {}, {}
    for ch in CHANNELS:
        modes[ch], filters[ch], wf[ch], scores[ch] = walk_forward_filter(
            data, splits, ch, schedule, group_candidates=group_candidates, with_spindle=with_spindle,
            fold_starts=fold_starts, tau_grid=tau_grid, ratio_grid=ratio_grid, evaluations=evaluations,
            load_probing=load_probing, arx_cache=arx_cache)
        by_mode, inputs[ch] = calibrated_arx(data, splits.n_train, ch, group_candidates, with_spindle, arx_cache)
        preds[ch] = by_mode[modes[ch]]
        if progress is not None:
            progress()
    Y = np.column_stack([data.displacement_um[ch] for ch in CHANNELS])
    P = np.column_stack([preds[ch] for ch in CHANNELS])
    r = run_probe_updates(data.time_s, Y, P, splits.n_train, schedule, [filters[ch] for ch in CHANNELS],
                          last_calibration_probe_s=last_calibration_probe_s(data, splits.n_train),
                          load_change_rows=load_change_rows(data) if load_probing else ())
    n_cal = int(math.ceil(splits.n_train / grid_step_rows(data)))
    comp = {ch: r.compensation[:, i] for i, ch in enumerate(CHANNELS)}
    return CalibratedTalc(preds, comp, r.probe_rows, r.no_good_phases, n_cal, schedule, filters, modes, wf, scores,
                          inputs, r.load_change_phases)


def calibrated_talc_figures(data: FlThermalData, splits: Splits, result: CalibratedTalc) -> dict[str, Any]:
    """MAE per channel and split, the chosen filters, probings and Q_prod counted two ways:
    ``q_prod_pct`` over the whole recording, charging the calibration phase one probing per 5-min
    grid sample of the training rows; ``q_prod_after_calibration_pct`` over the rows after it."""
    figures: dict[str, Any] = {}
    first = result.probe_rows[0] if result.probe_rows else splits.n
    blind, seen = slice(splits.n_train, min(first, splits.test_end)), slice(min(first, splits.test_end),
                                                                          splits.test_end)
    step = grid_step_rows(data)
    measured = [((splits.n_train - 1) // step) * step] + list(result.probe_rows)   # last calibration probing on
    for ch in CHANNELS:
        y = data.displacement_um[ch]
        c, p, f = result.compensation[ch], result.prediction[ch], result.filters[ch]
        held = hold_probes(y, measured, splits.n)    # the generic baseline: hold this model's own probes
        figures[ch] = {"mae_um": round(mae(y[splits.test], c[splits.test]), 3),
                       "mae_validation_um": round(mae(y[splits.validation], c[splits.validation]), 3),
                       "hold_last_measurement_mae_um": round(mae(y[splits.test], held[splits.test]), 3),
                       "hold_last_measurement_mae_validation_um": round(mae(y[splits.validation],
                                                                            held[splits.validation]), 3),
                       # test rows before / from the first probing after calibration (blind / probed)
                       "mae_before_first_probe_um": round(mae(y[blind], c[blind]), 3),
                       "mae_from_first_probe_um": round(mae(y[seen], c[seen]), 3),
                       "open_loop_mae_um": round(mae(y[splits.test], p[splits.test]), 3),
                       "open_loop_mae_validation_um": round(mae(y[splits.validation], p[splits.validation]), 3),
                       "walk_forward_mae_um": round(result.walk_forward_mae_um[ch], 3),
                       "bias_time_constant_h": round(f.bias_time_constant_s / 3600.0, 3),
                       "noise_ratio": f.noise_ratio, "evaluation": result.evaluation[ch],
                       "inputs": result.inputs[ch]}
    dur = result.schedule.probe_duration_s
    total_s = float(data.time_s[-1] - data.time_s[0])
    after_s = float(data.time_s[-1] - data.time_s[splits.n_train - 1])
    rows = result.probe_rows
    figures["acl_um"] = result.schedule.acl_um
    figures["calibration_probings"] = result.calibration_probings
    figures["probing_cycles"] = result.calibration_probings + len(rows)
    figures["probing_cycles_after_calibration"] = len(rows)
    figures["probing_cycles_test_rows"] = int(sum(splits.n_train <= r < splits.test_end for r in rows))
    figures["probing_cycles_validation_rows"] = int(sum(splits.test_end <= r < splits.n for r in rows))
    figures["no_good_phases"] = result.no_good_phases
    figures["load_change_phases"] = result.load_change_phases
    figures["q_prod_pct"] = round(q_prod_pct(result.calibration_probings + len(rows), total_s, dur), 2)
    figures["q_prod_after_calibration_pct"] = round(q_prod_pct(len(rows), after_s, dur), 2)
    figures["calibration_end_h"] = round(float(data.time_s[splits.n_train - 1] / 3600.0), 2)
    figures["first_probe_after_calibration_h"] = (round(float(data.time_s[first] / 3600.0), 2)
                                                  if first < splits.n else None)
    return figures
