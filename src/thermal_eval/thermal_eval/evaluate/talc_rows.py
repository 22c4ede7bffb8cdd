"""TALC fitted on the training rows: closed-loop rows of ``thermal-comp evaluate`` on any recording.

Model: TALC's ARX model class on the 5-min grid (:func:`thermal_eval.evaluate.open_loop_models.arx_model`:
inputs = medoid sensors of k-means groups, optionally plus the recording's machine inputs, orders
by MDL), identified on the training rows, which are its calibration phase
(:mod:`thermal_eval.evaluate.training_fit`: one charged probing per grid sample). After calibration
the ARX runs in simulation mode on the temperatures (read between its grid samples with the
current inputs, ``subgrid``, or held, ``grid_hold``), and every probing updates the model's
state through the slow-error Kalman filter of :mod:`talc_model.probing.probe_update` /
:mod:`talc_model.loop.slow_error_filter` (time constant tau, noise ratio r; r = 0 is TALC's
"measurement replaces prediction"). A residual beyond the user's tolerance (the action-control
limit) starts a no-good phase of 12 probes ``min_gap_s`` apart; ``load_probing`` also starts one
at every change of a machine input (the model is least sure right after a load change). The
ARX parameters are not re-estimated: a probe adds one sample to the hundreds of the calibration.

Probing follows the user's :class:`thermal_eval.evaluate.adaptive.ProbingBudget`: a probing every
``probe_every_h`` after the previous cycle, the no-good / load phases as the model's own
probings, all within the hard cap ``max_probes_per_h`` after calibration (a refused probing is
asked again at the next row). Per channel the (evaluation mode, tau, r) with the lowest mean MAE
over walk-forward folds inside the training rows (the same budget) is taken.
No rclpy here.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from talc_model.probing.probe_update import ProbeSchedule, run_probe_updates
from talc_model.loop.slow_error_filter import SlowErrorFilter
from thermal_comp_common.metrics import mae
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.training_fit import (FOLD_STARTS, TrainingFitError, calibration_grid_rows, load_change_rows,
                                           walk_forward_fold_rows)
from thermal_eval.evaluate.spec import EvaluationData
from thermal_eval.evaluate.open_loop_models import GROUP_CANDIDATES, arx_model

#: Slow-error time constants tried (s): 30 min (spindle nose) ... 24 h (a drifting reference).
BIAS_TAU_GRID_S = (1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 86400.0)
#: Fast / slow model-error variance ratios tried (0 = the probe is the slow error exactly).
NOISE_RATIO_GRID = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0)
#: How the 5-min ARX is read between its grid samples.
EVALUATIONS = ("grid_hold", "subgrid")


def probe_schedule(budget: ProbingBudget) -> ProbeSchedule:
    """TALC's schedule from the user's budget: interval, cycle, tolerance as the ACL, the
    no-good phase's probings ``min_gap_s`` apart."""
    return ProbeSchedule(probe_interval_s=budget.probe_every_h * 3600.0, probe_duration_s=budget.probe_duration_s,
                         acl_um=budget.tolerance_um, ng_interval_s=budget.min_gap_s)


@dataclass
class TrainingFitTalc:
    prediction: dict[str, np.ndarray]     # open-loop ARX after calibration (NaN on calibration rows)
    compensation: dict[str, np.ndarray]   # with the probe state updates
    calibration_rows: list[int]           # the charged calibration probings (grid samples)
    probe_rows: list[int]                 # after calibration
    no_good_phases: int
    load_change_phases: int
    refused_steps: int
    settings: dict[str, dict[str, Any]] = field(default_factory=dict)   # per channel: what was chosen


def training_fit_arx(data: EvaluationData, n_calibration: int, channel: str, group_candidates: Sequence[int],
                     with_inputs: bool, cache: dict | None = None) -> tuple[dict[str, np.ndarray], list[str]]:
    """ARX identified on rows < n_calibration only (inputs, orders, parameters), simulated after:
    ({evaluation mode: prediction for every row, NaN before n_calibration}, input names).
    An unidentifiable ARX raises :class:`thermal_eval.evaluate.model_selection.ModelFailure`."""
    key = (channel, int(n_calibration), bool(with_inputs), tuple(group_candidates))
    if cache is not None and key in cache:
        return cache[key]
    held = arx_model("arx", with_inputs, False, group_candidates)
    sub = arx_model("arx", with_inputs, True, group_candidates)
    params = held.select(data, channel, n_calibration)
    out: dict[str, np.ndarray] = {}
    for mode, spec in (("grid_hold", held), ("subgrid", sub)):
        p = np.array(spec.predict(data, channel, params, n_calibration), dtype=float)
        p[:n_calibration] = np.nan
        out[mode] = p
    res = (out, list(params["inputs"]) + (list(data.input_names) if with_inputs else []))
    if cache is not None:
        cache[key] = res
    return res


def _replay(data, y, pred, k, stop, schedule, filters, budget, changes):
    return run_probe_updates(data.time_s, y, pred, k, schedule, filters, stop=stop,
                             last_calibration_probe_s=float(data.time_s[calibration_grid_rows(data.time_s, k)[-1]]),
                             load_change_rows=changes, max_probes_per_h=budget.max_probes_per_h)


def walk_forward_filter(data: EvaluationData, channel: str, budget: ProbingBudget, *,
                        group_candidates: Sequence[int] = GROUP_CANDIDATES, with_inputs: bool = False,
                        fold_starts: Sequence[float] = FOLD_STARTS, tau_grid: Sequence[float] = BIAS_TAU_GRID_S,
                        ratio_grid: Sequence[float] = NOISE_RATIO_GRID, evaluations: Sequence[str] = EVALUATIONS,
                        load_probing: bool = False, arx_cache: dict | None = None
                        ) -> tuple[str, SlowErrorFilter, float]:
    """The channel's (evaluation mode, slow-error filter, mean fold MAE) chosen by the
    walk-forward replay inside the training rows (the channel replayed alone under the budget)."""
    unknown = sorted(set(evaluations) - set(EVALUATIONS))
    if unknown or not evaluations:
        raise TrainingFitError(f"evaluations: {list(evaluations)!r} must be a non-empty subset of {list(EVALUATIONS)}")
    n = data.split.n_train
    y = data.displacement_um[channel]
    schedule = probe_schedule(budget)
    folds = [(k, training_fit_arx(data, k, channel, group_candidates, with_inputs, arx_cache)[0])
             for k in walk_forward_fold_rows(fold_starts, n)]
    changes = load_change_rows(data) if load_probing else []
    best: tuple[float, str, SlowErrorFilter | None] = (math.inf, "", None)
    for mode, tau, ratio in itertools.product(evaluations, tau_grid, ratio_grid):
        flt = SlowErrorFilter(float(tau), float(ratio))
        errs = [mae(y[k:n], _replay(data, y, preds[mode], k, n, schedule, [flt], budget, changes).compensation[k:n, 0])
                for k, preds in folds]
        if float(np.mean(errs)) < best[0]:
            best = (float(np.mean(errs)), mode, flt)
    if best[2] is None:
        raise TrainingFitError(f"{channel}: no walk-forward fold could be scored")
    return best[1], best[2], best[0]


def run_training_fit_talc(data: EvaluationData, budget: ProbingBudget, *, with_inputs: bool = False,
                          load_probing: bool = False, group_candidates: Sequence[int] = GROUP_CANDIDATES,
                          arx_cache: dict | None = None, **selection) -> TrainingFitTalc:
    """Choose each channel's filter on the training rows, fit on all of them, then replay
    the rows after under the budget (one probing measures every channel)."""
    if with_inputs and data.inputs is None:
        raise TrainingFitError("with_inputs: the recording has no machine-input columns")
    if load_probing and not load_change_rows(data):
        raise TrainingFitError("load_probing: no machine input of the recording ever changes")
    n = data.split.n_train
    preds, filters, settings = {}, [], {}
    for ch in data.channels:
        mode, flt, wf = walk_forward_filter(data, ch, budget, group_candidates=group_candidates,
                                            with_inputs=with_inputs, load_probing=load_probing,
                                            arx_cache=arx_cache, **selection)
        by_mode, inputs = training_fit_arx(data, n, ch, group_candidates, with_inputs, arx_cache)
        preds[ch] = by_mode[mode]
        filters.append(flt)
        settings[ch] = {"evaluation": mode, "bias_time_constant_h": round(flt.bias_time_constant_s / 3600.0, 3),
                        "noise_ratio": flt.noise_ratio, "walk_forward_mae_um": round(wf, 3), "inputs": inputs}
    Y = np.column_stack([data.displacement_um[ch] for ch in data.channels])
    P = np.column_stack([preds[ch] for ch in data.channels])
    r = _replay(data, Y, P, n, len(data), probe_schedule(budget), filters, budget,
                load_change_rows(data) if load_probing else [])
    comp = {ch: r.compensation[:, i] for i, ch in enumerate(data.channels)}
    return TrainingFitTalc(preds, comp, [int(k) for k in calibration_grid_rows(data.time_s, n)], list(r.probe_rows),
                          r.no_good_phases, r.load_change_phases, r.refused_steps, settings)
