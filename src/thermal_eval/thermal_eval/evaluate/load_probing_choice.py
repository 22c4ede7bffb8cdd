"""Whether, and how, a model probes after machine-input steps: chosen on the training rows only.

``evaluate --load-probing``: per model (each model has its own probings), the load-change rule
of :mod:`talc_model.open_loop.load_probing` is off or on with a delay D and a bucket depth B, whichever
gives the smallest MAE on the walk-forward inside the training rows that the gain update and the
re-fit are chosen on (docs/evaluate.md, "re-fit at each probing"): the model fitted on the first half of the
training rows (``first`` = OOF_MIN_FRACTION x n_train), its adaptive mode run over the second
half exactly as on the held-out rows (:func:`thermal_eval.evaluate.adaptive.run_adaptive`, the same
schedule and update), the MAE averaged over the channels and over the probe phases. No held-out
row is read. No machine inputs, or no step on the training rows: the rule is off.
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Mapping

import numpy as np

from thermal_eval.evaluate.adaptive import ProbingBudget, phase_budgets, run_adaptive
from thermal_eval.evaluate.spec import EvaluationData, Split
from talc_model.open_loop.load_probing import DELAYS_MIN, DEPTHS, input_steps
from thermal_eval.evaluate.model_selection import ModelSpec, out_of_fold_prediction
from talc_model.open_loop.probe_refit import RidgeRefit, ridge_refit


def training_rows(data: EvaluationData, first: int) -> EvaluationData:
    """The training rows as a recording whose calibration ends at ``first`` and whose rows
    [first, n_train) are the walk-forward's held-out rows."""
    n = data.split.n_train
    return EvaluationData(data.time_s[:n], data.temperatures[:n], data.sensors,
                          None if data.inputs is None else data.inputs[:n], data.input_names,
                          {c: y[:n] for c, y in data.displacement_um.items()},
                          Split(first, slice(first, n), slice(n, n), n), data.source,
                          run_id=None if data.run_id is None else data.run_id[:n])


def fitted_on_first(data: EvaluationData, model: ModelSpec, channel: str, params: dict, first: int,
                    regain: Any = None) -> tuple[np.ndarray, tuple[np.ndarray, int], Any]:
    """The model fitted on rows < ``first`` (params kept): its prediction, its out-of-fold
    prediction inside rows < ``first`` and its update (the re-fit or gain update with the chosen
    weight / penalty), each cut to the training rows."""
    n = data.split.n_train
    p = model.predict(data, channel, params, first)[:n]
    oof, oof_first = out_of_fold_prediction(model, data, channel, params, first)
    upd = None
    if isinstance(regain, RidgeRefit):
        half = ridge_refit(data.time_s, data.temperatures, data.displacement_um[channel], first, params["taus_s"],
                           params["alpha"], regain.weight, regain.own_level)
        upd = replace(half, z=half.z[:n])
    elif regain is not None:
        _, *chosen = regain                         # (contributions, penalty[, forgetting])
        upd = (np.asarray(model.contributions(data, channel, params, first))[:n], *chosen)
    return p, (oof[:n], oof_first), upd


def candidates(budget: ProbingBudget) -> list[ProbingBudget]:
    """Off (the budget as given), then every delay x depth of the rule."""
    return [replace(budget, load_delay_min=None)] + [
        replace(budget, load_delay_min=d, bucket_depth=b) for d in DELAYS_MIN for b in DEPTHS]


def _key(b: ProbingBudget) -> str:
    return "off" if b.load_delay_min is None else f"{b.load_delay_min:g}min/{b.bucket_depth:g}"


def choose_load_probing(data: EvaluationData, first: int, fits: Mapping[str, tuple], budget: ProbingBudget,
                        phases: int) -> tuple[ProbingBudget, dict[str, Any]]:
    """The budget (rule off, or on with its delay and depth) with the smallest walk-forward MAE,
    and the JSON of the choice. ``fits``: per channel :func:`fitted_on_first`'s triple."""
    steps = input_steps(data.inputs, data.split.n_train)
    in_train = int(np.sum(steps < data.split.n_train))
    if in_train == 0:
        why = "no machine inputs" if data.inputs is None else "no machine-input step on the training rows"
        return replace(budget, load_delay_min=None), {"chosen": "off", "why": why}
    if not fits:
        return replace(budget, load_delay_min=None), {"chosen": "off", "why": "no channel has a fitted model"}
    wf = training_rows(data, first)
    preds = {c: f[0] for c, f in fits.items()}
    oofs = {c: f[1] for c, f in fits.items()}
    regain = {c: f[2] for c, f in fits.items() if f[2] is not None}
    scores: dict[str, float] = {}
    counts: dict[str, list[int]] = {}
    for cand in candidates(budget):
        maes, n_probes = [], []
        for b in phase_budgets(cand, phases):
            res = run_adaptive(wf, preds, oofs, b, regain)
            e = [np.nanmean(np.abs(wf.displacement_um[c][first:] - res.compensation[c][first:])) for c in preds]
            maes.append(float(np.mean(e)))
            n_probes.append(len(res.probe_rows))
        scores[_key(cand)] = float(np.mean(maes)) if all(map(math.isfinite, maes)) else math.inf
        counts[_key(cand)] = n_probes
    best = min(candidates(budget), key=lambda b: scores[_key(b)])
    info = {"chosen": _key(best), "walk_forward_rows": [first, data.split.n_train], "walk_forward_phases": phases,
            "steps_on_training_rows": in_train, "walk_forward_mae_um": {k: round(v, 3) for k, v in scores.items()},
            "walk_forward_probings": counts}
    return best, info
