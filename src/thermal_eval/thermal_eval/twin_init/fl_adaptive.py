"""``bench twin-init``, part (c): the init twin's soft sensors as an ``evaluate`` model on FL_THERMAL.

The twin made by ``twin init`` from the training rows is run over the whole recording driven
only by what the cell knows at each instant (the spindle speed, the hall sensor t11 and the
coolant return t4: a simulation is causal), and its node temperatures (sensed and hidden
bodies) and its displacement channels are the features of one more ``evaluate`` model,
``twin_soft_sensors``: per channel either the twin's own displacement plus a level, or a ridge
on the twin's displacement and node temperatures, chosen by the same expanding walk-forward
inside the training rows as the lagged ridge's. It goes through ``evaluate`` beside every
data-only model (the defaults and the opt-in update rows but the slow static GP): the same
adaptive mode, probing budget (<= 1 per hour), probe phases and holding baseline.

Known optimism, inside the training rows only: the twin was identified on the training rows,
so the walk-forward that chooses the candidate and sets the adaptive blend's first weight sees
twin features fitted on rows after each fold's end. Test and validation rows are never used.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from thermal_comp_common.metrics import mae
from thermal_twin.diagnose.twin_eval import node_states, outputs_from_states
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.inputs_timeline import timeline_from_recording

from talc_model.open_loop.lagged_temperature_model import walk_forward_folds
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.model_selection import ModelSpec
from thermal_eval.evaluate.run import available_models, evaluate
from thermal_eval.evaluate.spec import EvaluationData

NAME = "twin_soft_sensors"
#: ridge penalties relative to the number of fitted rows (standardised features)
ALPHAS = (1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: the data-only rows beside it: evaluate's defaults plus these opt-in update rows (the static GP
#: is left out: it dominated evaluate's wall time on FL_THERMAL and was worse than the training mean)
DATA_ONLY_OPT_IN = ("lagged_ridge_gain_update", "arx_subgrid_gain_forgetting", "lagged_ridge_refit",
                    "lowpass_ridge_refit")
#: the probing clock's phases every adaptive row is scored at (docs/evaluate.md: phase mean)
PROBE_PHASES = 6


def soft_sensors(twin_path: str, rec) -> tuple[np.ndarray, list[str], dict[str, np.ndarray]]:
    """(node temperatures N x nodes, node names, the twin's outputs by column) over ``rec``."""
    m = load_machine(twin_path)
    net, t, X, tb = node_states(m, rec.time_s, timeline_from_recording(m, rec).resolved(m))
    return np.asarray(X, float), list(net.node_names), outputs_from_states(m, net, t, X, tb)


def _fit(F: np.ndarray, y: np.ndarray, n_fit: int, alpha: float | None) -> np.ndarray:
    """Prediction of every row from rows < n_fit: alpha None is column 0 (the twin's own channel)
    plus the mean residual; else a ridge on the standardised columns, intercept free."""
    f, yy = F[:n_fit], y[:n_fit]
    ok = np.isfinite(f).all(axis=1) & np.isfinite(yy)
    if alpha is None:
        return F[:, 0] + float(np.mean(yy[ok] - f[ok, 0]))
    mu, sd = f[ok].mean(axis=0), f[ok].std(axis=0)
    sd[sd <= 1e-12] = 1.0
    Z = (f[ok] - mu) / sd
    ym = float(yy[ok].mean())
    coef = np.linalg.solve(Z.T @ Z + alpha * ok.sum() * np.eye(Z.shape[1]), Z.T @ (yy[ok] - ym))
    return ym + ((F - mu) / sd) @ coef


def twin_model(features: Mapping[str, np.ndarray]) -> ModelSpec:
    """The ``evaluate`` model on the twin's soft sensors; ``features[channel]`` is rows x k with
    the twin's own displacement of that channel in column 0 and its node temperatures after."""
    candidates: list[float | None] = [None, *ALPHAS]

    def select(data: EvaluationData, channel: str, n_fit: int) -> dict:
        y, F = data.displacement_um[channel], features[channel]
        scores = []
        for a in candidates:
            err = [mae(y[v0:v1], _fit(F, y, end, a)[v0:v1]) for end, v0, v1 in walk_forward_folds(n_fit, 4, 0.5)]
            scores.append(float(np.mean(err)))
        best = int(np.argmin(scores))
        return {"alpha": candidates[best], "walk_forward_mae_um": round(scores[best], 3),
                "candidates": {("level" if a is None else f"ridge {a:g}"): round(s, 3)
                               for a, s in zip(candidates, scores)}}

    def predict(data: EvaluationData, channel: str, params: dict, n_fit: int) -> np.ndarray:
        return _fit(features[channel], data.displacement_um[channel], n_fit, params["alpha"])

    return ModelSpec(NAME, "model", "the init twin's soft sensors: its displacement (+ level) or a ridge on "
                     "its displacement and node temperatures (walk-forward)", select, predict)


def channel_features(X: np.ndarray, outputs: Mapping[str, np.ndarray], channels) -> dict[str, np.ndarray]:
    """Per evaluate channel ``chK``: the twin's column ``chK_um`` then every node temperature."""
    return {ch: np.column_stack([np.asarray(outputs[f"{ch}_um"], float), X]) for ch in channels}


def run_rows(data: EvaluationData, features: Mapping[str, np.ndarray], budget: ProbingBudget | None = None,
             probe_phases: int = PROBE_PHASES) -> dict[str, Any]:
    """``evaluate``'s figures with the twin row beside every data-only row (serial: the twin row's
    features live in this process)."""
    models = available_models(data, also=DATA_ONLY_OPT_IN) + [twin_model(features)]
    return evaluate(data, models=models, budget=budget, probe_phases=probe_phases, show_progress=False).figures


def _phase_mean(cell: dict) -> dict:
    return cell["phases"]["mean"] if "phases" in cell else cell


def _pair(c: dict, prefix: str = "") -> list[float]:
    return [c[f"{prefix}mae_test_um"], c[f"{prefix}mae_validation_um"]]


def data_only_rows(figures: Mapping[str, Any]) -> dict[str, dict[str, list[float]]]:
    """Every data-only adaptive row with a figure on every channel: name -> channel -> phase-mean
    MAE [test, validation]."""
    out = {}
    for name, row in figures["adaptive"].items():
        cells = row.get("channels", {})
        if name == NAME or "failed" in row or any("failed" in cells.get(c, {"failed": 1}) for c in figures["channels"]):
            continue
        out[name] = {c: _pair(_phase_mean(cells[c])) for c in figures["channels"]}
    return out


def best_row(rows: Mapping[str, Mapping[str, list[float]]]) -> str:
    """``evaluate``'s best adaptive row (bench evaluate's ``best_adaptive`` rule) on the phase mean:
    the smallest worst-channel MAE over both held-out windows."""
    return min(rows, key=lambda n: max(max(v) for v in rows[n].values()))


def _wins(twin: Mapping[str, list[float]], ref: Mapping[str, list[float]]) -> dict[str, int]:
    return {"mean_of_windows": sum(float(np.mean(twin[c])) < float(np.mean(ref[c])) for c in twin),
            "test": sum(twin[c][0] < ref[c][0] for c in twin), "validation": sum(twin[c][1] < ref[c][1] for c in twin)}


def comparison(figures: Mapping[str, Any]) -> dict[str, Any]:
    """Per channel, on the phase mean of the adaptive MAE [test, validation]: the twin row, holding
    the twin row's own probes, evaluate's best data-only adaptive row (:func:`best_row`) and the
    best data-only row of each channel (the smallest mean of the two windows: a pick on the
    held-out rows, the strictest reference), and the open-loop twin row, training mean, static
    regression and lagged ridge; then on how many channels the twin row is below each reference
    (mean of the two windows, and each window)."""
    ad, ol = figures["adaptive"], figures["open_loop"]
    rows = data_only_rows(figures)
    best = best_row(rows)
    twin = {c: _pair(_phase_mean(ad[NAME]["channels"][c])) for c in figures["channels"]}
    per_channel = {c: min(rows, key=lambda n: float(np.mean(rows[n][c]))) for c in figures["channels"]}
    out: dict[str, Any] = {"best data-only row": best, "channels": {}, "probings_per_h": {}}
    for name, row in ad.items():
        ph = row.get("probe_phases")
        out["probings_per_h"][name] = max(ph["probings_per_h_after_calibration"]) if ph else \
            row.get("probings_per_h_after_calibration")
    for ch in figures["channels"]:
        out["channels"][ch] = {
            "twin adaptive": twin[ch], "holding": _pair(_phase_mean(ad[NAME]["channels"][ch]), "hold_own_probes_"),
            f"best data-only adaptive ({best})": rows[best][ch],
            "best data-only adaptive of the channel": rows[per_channel[ch]][ch], "best of the channel": per_channel[ch],
            "twin open loop": _pair(ol[NAME]["channels"][ch]),
            "training mean": _pair(ol["train_mean"]["channels"][ch]),
            "static regression": _pair(ol["static_ls"]["channels"][ch]),
            "lagged ridge open loop": _pair(ol["lagged_ridge"]["channels"][ch]) if "lagged_ridge" in ol else None,
            "twin choice": ol[NAME]["channels"][ch].get("params", {}).get("alpha", "n/a")}
    out["better_than_best_row"] = _wins(twin, rows[best])
    out["better_than_best_of_each_channel"] = _wins(twin, {c: rows[per_channel[c]][c] for c in twin})
    out["better_than_each_row"] = {n: _wins(twin, v)["mean_of_windows"] for n, v in rows.items()}
    return out
