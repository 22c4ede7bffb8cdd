"""One evaluation: every baseline and model, open loop and adaptive, on one recording.

Per model and channel: select on the training rows (walk-forward), refit on them, predict every
row open loop, score the validation and test rows; in adaptive mode the same prediction drives
:mod:`thermal_eval.evaluate.adaptive`. A model that fails on a channel (unidentifiable, diverged,
any exception) is recorded with its reason and the other models and channels go on.
Figures are plain dicts (the JSON); arrays for the plots are returned beside them.
Each model row is one task of :func:`thermal_comp_common.runtime.task_engine.map_tasks` (serial, a local
process pool or a dask cluster): rows are independent and put back in the models' order.
"""
from __future__ import annotations

import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.metrics import mae, p99, rmse
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_eval.evaluate.adaptive import ProbingBudget, phase_budgets, probe_counts, run_adaptive
from thermal_eval.evaluate.baselines import BASELINES
from thermal_eval.evaluate.model_rows import CLOSED_LOOP, hold_probes, run_closed_loop
from thermal_eval.evaluate.spec import EvaluationData, SpecError, closest
from thermal_eval.evaluate.model_selection import OOF_MIN_FRACTION, ModelSpec, checked_prediction, out_of_fold_prediction
from talc_model.open_loop.probe_gain_update import FORGETTINGS, PENALTIES, choose_update
from talc_model.open_loop.probe_refit import REFIT_ROWS, refit_choice
from talc_model.open_loop.load_probing import input_steps
from thermal_eval.evaluate.load_probing_choice import choose_load_probing, fitted_on_first
from thermal_eval.evaluate.open_loop_models import MODELS
from thermal_eval.evaluate.opt_in import OPT_IN

#: baselines whose adaptive row would only be holding again
NOT_ADAPTIVE = ("train_mean", "hold_last_training")
#: gain-update rows whose older probe pairs fade (penalty and forgetting chosen together on the
#: training walk-forward averaged over this many probe phases, so the choice is not one phase's luck)
FORGETTING_ROWS = ("arx_subgrid_gain_forgetting",)
WALK_FORWARD_PHASES = 6
#: every model a task may name
REGISTRY: dict[str, ModelSpec] = {m.name: m for m in BASELINES + MODELS}


@dataclass
class EvaluationResult:
    figures: dict[str, Any]
    open_loop: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)     # model -> ch -> prediction
    adaptive: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)      # model -> ch -> compensation
    hold: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    probe_rows: dict[str, list[int]] = field(default_factory=dict)


def available_models(data: EvaluationData, names: Sequence[str] | None = None,
                     also: Sequence[str] = ()) -> list[ModelSpec]:
    """The models of the table: ``names`` only (with every baseline), or the defaults (every
    model the recording has inputs for, without the opt-in ones) plus ``also``."""
    every = BASELINES + MODELS
    if also and not names:
        names = [m.name for m in available_models(data)] + list(also)
        names = list(dict.fromkeys(names))
    if names:
        known = {m.name: m for m in every}
        bad = [n for n in names if n not in known]
        if bad:
            raise SpecError(f"--models: {bad[0]!r} is not a model{closest(bad[0], list(known))}")
        chosen = [known[n] for n in names]
        return [b for b in BASELINES if b not in chosen] + chosen   # baselines are always in the table
    return [m for m in every if not (m.needs_inputs and data.inputs is None) and m.name not in OPT_IN]


#: the error figures of every cell (um): one per held-out window
ERROR_FIGURES = (("mae", mae), ("rmse", rmse), ("p99", p99))
#: the baseline every open-loop ratio is stated against (a linear regression on the same temperatures)
RATIO_BASELINE = "static_ls"


def window_scores(y: np.ndarray, p: np.ndarray, sl: slice, window: str) -> dict[str, float | None]:
    """MAE, RMSE and P99 of |y - p| on the rows of one window (None when it has no row)."""
    ok = np.isfinite(y[sl]) & np.isfinite(p[sl])
    out: dict[str, float | None] = {}
    for k, f in ERROR_FIGURES:
        out[f"{k}_{window}_um"] = round(f(y[sl][ok], p[sl][ok]), 3) if ok.any() else None
    return out


def _scores(data: EvaluationData, y: np.ndarray, p: np.ndarray) -> dict[str, float | None]:
    s = data.split
    return {**window_scores(y, p, s.test, "test"), **window_scores(y, p, s.validation, "validation")}


def _ratio(a: float | None, b: float | None) -> float | None:
    return round(a / b, 3) if a is not None and b is not None and b > 0 else None


def _reason(exc: BaseException) -> str:
    frame = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    where = f" ({frame.filename.rsplit('/', 1)[-1]}:{frame.lineno})" if frame else ""
    return f"{type(exc).__name__}: {exc}"[:300] + where


@dataclass
class ModelRow:
    """One model's row of the evaluation: its figures and arrays (what a task returns)."""

    name: str
    open_loop: dict[str, Any] | None
    predictions: dict[str, np.ndarray]
    adaptive: dict[str, Any] | None = None
    compensation: dict[str, np.ndarray] | None = None
    hold: dict[str, np.ndarray] | None = None
    probe_rows: list[int] | None = None


def model_row(data: EvaluationData, model: ModelSpec, adaptive: bool, budget: ProbingBudget,
              probe_phases: int = 1, load_probing: bool = False) -> ModelRow:
    """Every channel of one model, open loop and (unless a plain baseline) adaptive, the
    adaptive mode at ``probe_phases`` phases of the probing clock (:func:`_adaptive_row`).
    ``load_probing``: the load-change rule off or on (delay, bucket depth) as the training-row
    walk-forward chooses (:mod:`thermal_eval.evaluate.load_probing_choice`)."""
    s = data.split
    ol: dict[str, Any] = {"kind": model.kind, "description": model.description, "channels": {}}
    preds, oofs, regain, fits = {}, {}, {}, {}
    first = int(round(OOF_MIN_FRACTION * s.n_train))
    load = (adaptive and load_probing and model.name not in NOT_ADAPTIVE
            and bool(np.sum(input_steps(data.inputs, s.n_train) < s.n_train)))
    t0 = time.perf_counter()
    for ch in data.channels:
        y = data.displacement_um[ch]
        try:
            params = model.select(data, ch, s.n_train)
            p = checked_prediction(model.predict(data, ch, params, s.n_train), data, slice(s.n_train, s.n), model.name)
            cell = _scores(data, y, p)
            cell["params"] = {k: v for k, v in params.items() if k != "orders"}
            if adaptive and model.name not in NOT_ADAPTIVE:
                oofs[ch] = out_of_fold_prediction(model, data, ch, params, s.n_train)
                if model.contributions is not None:
                    regain[ch], cell["probe_gain_update"] = _gain_update_choice(data, model, ch, params, budget)
                elif model.name in REFIT_ROWS:
                    regain[ch], cell["probe_refit"] = refit_choice(
                        data, ch, params, int(round(OOF_MIN_FRACTION * s.n_train)), 3600.0 * budget.interval_h,
                        WALK_FORWARD_PHASES)
                if load:
                    fits[ch] = fitted_on_first(data, model, ch, params, first, regain.get(ch))
            preds[ch] = p
        except Exception as exc:   # one failing model/channel is one row with its reason
            cell = {"failed": _reason(exc)}
        ol["channels"][ch] = cell
    ol["seconds"] = round(time.perf_counter() - t0, 1)
    row = ModelRow(model.name, ol, preds)
    if adaptive and model.name not in NOT_ADAPTIVE:
        choice = None
        if load_probing:
            fits = {c: f for c, f in fits.items() if c in preds}
            budget, choice = choose_load_probing(data, first, fits, budget, WALK_FORWARD_PHASES)
        _adaptive_row(data, model, preds, oofs, budget, row, regain, probe_phases)
        if choice is not None:
            row.adaptive["load_probing"] = choice
    return row


def _gain_update_choice(data: EvaluationData, model: ModelSpec, ch: str, params: dict, budget: ProbingBudget):
    """The model's contributions on rows < n_train, and the gain update's penalty (and, for
    :data:`FORGETTING_ROWS`, forgetting) chosen by a walk-forward inside the training rows: the
    model fitted on the first half, probed at the budget's interval over the second half."""
    n_train = data.split.n_train
    first = int(round(OOF_MIN_FRACTION * n_train))
    every_s = 3600.0 * budget.interval_h
    p_fit = model.predict(data, ch, params, first)
    fades = model.name in FORGETTING_ROWS
    (penalty, forgetting), scores = choose_update(
        data.time_s, data.displacement_um[ch], p_fit, model.contributions(data, ch, params, first), first, n_train,
        every_s, PENALTIES, FORGETTINGS if fades else (1.0,), WALK_FORWARD_PHASES if fades else 1)
    info = {"penalty": penalty, "walk_forward_rows": [first, n_train],
            "walk_forward_mae_um": {k: round(v, 3) for k, v in scores.items()}}
    chosen: tuple = (penalty,)
    if fades:
        info.update(forgetting=forgetting, walk_forward_phases=WALK_FORWARD_PHASES)
        chosen = (penalty, forgetting)
    return (model.contributions(data, ch, params, n_train), *chosen), info


def _beside_hold(data: EvaluationData, y: np.ndarray, compensation: np.ndarray, hold: np.ndarray) -> dict[str, Any]:
    """One channel of one adaptive run: MAE, RMSE, P99, holding the same probes, their ratio (MAE)."""
    cell = _scores(data, y, compensation)
    h = _scores(data, y, hold)
    for k, v in h.items():
        cell[f"hold_own_probes_{k}"] = v
    for w in ("test", "validation"):
        cell[f"ratio_to_hold_{w}"] = _ratio(cell[f"mae_{w}_um"], h[f"mae_{w}_um"])
    return cell


def _adaptive_row(data, model, preds, oofs, budget, out: ModelRow, regain=None, probe_phases: int = 1) -> None:
    """The adaptive row: phase 0 (the budget's own schedule) gives the row's figures and arrays;
    with ``probe_phases`` K > 1 the whole adaptive run is repeated with the probing clock
    delayed by i/K of the interval, and each cell gets the phases' MAE, mean and worst."""
    row: dict[str, Any] = {"kind": model.kind, "channels": {}}
    out.adaptive = row
    usable = {c: p for c, p in preds.items() if c in oofs}
    if not usable:
        row["failed"] = "no channel has an open-loop prediction"
        return
    regain = {c: v for c, v in (regain or {}).items() if c in usable}
    runs = []
    try:
        for b in phase_budgets(budget, probe_phases):
            runs.append(run_adaptive(data, usable, oofs, b, regain))
    except Exception as exc:
        row["failed"] = _reason(exc)
        return
    ad = runs[0]
    for ch in data.channels:
        if ch not in usable:
            row["channels"][ch] = {"failed": "no open-loop prediction"}
            continue
        y = data.displacement_um[ch]
        cell = _beside_hold(data, y, ad.compensation[ch], ad.hold[ch])
        cell["corrected_model_mae_test_um"] = _scores(data, y, ad.corrected[ch])["mae_test_um"]
        cell["model_weight"] = round(ad.weights[ch], 3)
        cell.update(ad.rates[ch])
        if probe_phases > 1:
            cell["phases"] = phase_summary([_beside_hold(data, y, r.compensation[ch], r.hold[ch]) for r in runs])
        row["channels"][ch] = cell
    row.update(probe_counts(data, ad.probe_rows, budget))
    row["probings_asked_by_model"] = len(ad.triggered_rows)
    row["probings_after_input_steps"] = len(ad.load_rows)
    if probe_phases > 1:
        per = [probe_counts(data, r.probe_rows, budget) for r in runs]
        counted = ("probings_after_calibration", "probings_per_h_after_calibration", "probings_test",
                   "probings_validation")
        row["probe_phases"] = {"k": probe_phases,
                               "offsets_h": [round(b.phase_h, 4) for b in phase_budgets(budget, probe_phases)],
                               **{k: [p[k] for p in per] for k in counted},
                               "probings_after_input_steps": [len(r.load_rows) for r in runs]}
    out.compensation, out.hold, out.probe_rows = ad.compensation, ad.hold, ad.probe_rows


#: the figures of a phase's cell summarised over the phases
PHASE_KEYS = ("mae_test_um", "mae_validation_um", "hold_own_probes_mae_test_um", "hold_own_probes_mae_validation_um",
              "rmse_test_um", "rmse_validation_um", "p99_test_um", "p99_validation_um")


def phase_summary(cells: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per phase, the mean over phases (its ratio: mean MAE over mean holding MAE) and the worst
    phase (largest MAE, largest ratio to holding at that phase's own probes); an empty window's
    figures are None."""
    out: dict[str, Any] = {"by_phase": {k: [c[k] for c in cells] for k in PHASE_KEYS}}

    def agg(k: str, f) -> float | None:
        v = [c[k] for c in cells if c[k] is not None]
        return round(float(f(v)), 3) if v else None
    mean = {k: agg(k, np.mean) for k in PHASE_KEYS}
    worst = {k: agg(k, np.max) for k in PHASE_KEYS[:2]}
    for w in ("test", "validation"):
        mean[f"ratio_to_hold_{w}"] = _ratio(mean[f"mae_{w}_um"], mean[f"hold_own_probes_mae_{w}_um"])
        ratios = [c[f"ratio_to_hold_{w}"] for c in cells if c[f"ratio_to_hold_{w}"] is not None]
        worst[f"ratio_to_hold_{w}"] = max(ratios) if ratios else None
    out["mean"], out["worst"] = mean, worst
    return out


def closed_loop_row(data: EvaluationData, name: str, budget: ProbingBudget) -> ModelRow:
    """An adaptive row of one of the project's adaptive models (:mod:`thermal_eval.evaluate.model_rows`),
    beside holding its own probes at the same instants; a failure is the row's reason."""
    t0 = time.perf_counter()
    row: dict[str, Any] = {"kind": "closed_loop", "channels": {}}
    try:
        run = run_closed_loop(data, name, budget)
    except Exception as exc:
        row["failed"] = _reason(exc)
        return ModelRow(name, None, {}, row)
    n, hold = len(data), {}
    for ch in data.channels:
        y = data.displacement_um[ch]
        hold[ch] = hold_probes(y, run["probe_rows"], n)
        row["channels"][ch] = _beside_hold(data, y, run["compensation"][ch], np.nan_to_num(hold[ch]))
    after = run["probe_rows_after_calibration"]
    row.update({k: v for k, v in run.items() if k not in ("compensation", "probe_rows", "probe_rows_after_calibration")})
    s = data.split
    row["probings_test"] = sum(1 for r in after if s.test.start <= r < s.test.stop)
    row["probings_validation"] = sum(1 for r in after if s.validation.start <= r < s.validation.stop)
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return ModelRow(name, None, {}, row, run["compensation"], hold, run["probe_rows"])


def _row_task(shared: tuple, item: str | ModelSpec | tuple) -> ModelRow:
    """Task of the engine: one model row. ``item`` is a registered model's name (so the local
    pool pickles a string, not the model's closures), ``("closed_loop", name)``, or, for a model
    outside the registry, the spec itself (serial run or dask, which pickles closures)."""
    data, adaptive, budget, probe_phases, load_probing = shared
    if isinstance(item, tuple):
        return closed_loop_row(data, item[1], budget)
    model = REGISTRY[item] if isinstance(item, str) else item
    return model_row(data, model, adaptive, budget, probe_phases, load_probing)


def _add_row(result: EvaluationResult, row: ModelRow) -> None:
    if row.open_loop is not None:
        result.figures["open_loop"][row.name] = row.open_loop
        result.open_loop[row.name] = row.predictions
    if row.adaptive is not None:
        result.figures["adaptive"][row.name] = row.adaptive
    if row.compensation is not None:
        result.adaptive[row.name] = row.compensation
        result.hold[row.name] = row.hold
        result.probe_rows[row.name] = row.probe_rows


def _ratios_to_baseline(figures: dict[str, Any], channels: list[str]) -> None:
    """Open loop: each model's MAE over the named baseline's (:data:`RATIO_BASELINE`) on the same
    rows and channel; the best baseline per window is kept beside it, named."""
    ol = figures["open_loop"]
    base_row = ol.get(RATIO_BASELINE)
    figures["ratio_baseline"] = RATIO_BASELINE if base_row is not None else None
    for window in ("test", "validation"):
        key = f"mae_{window}_um"
        for ch in channels:
            base = [(v["channels"][ch][key], name) for name, v in ol.items() if v["kind"] == "baseline"
                    and v["channels"][ch].get(key) is not None and np.isfinite(v["channels"][ch][key])]
            if base:
                b, name = min(base)
                figures.setdefault("best_baseline_mae_um", {}).setdefault(window, {})[ch] = {"model": name, "mae_um": b}
            if base_row is None:
                continue
            ref = base_row["channels"][ch].get(key)
            for v in ol.values():
                cell = v["channels"][ch]
                if cell.get(key) is not None:
                    cell[f"ratio_to_{RATIO_BASELINE}_{window}"] = _ratio(cell[key], ref)


def evaluate(data: EvaluationData, *, models: Sequence[ModelSpec] | None = None, adaptive: bool = True,
             budget: ProbingBudget | None = None, show_progress: bool = True,
             engine: EngineSpec | None = None, closed_loop: Sequence[str] = (),
             probe_phases: int = 1, load_probing: bool = False) -> EvaluationResult:
    """The whole evaluation (figures + arrays for the report). Model rows are independent tasks
    of :func:`thermal_comp_common.runtime.task_engine.map_tasks` (serial by default, a local pool or a
    dask cluster with ``engine``); the rows are put back in the models' order, so the figures do
    not depend on the engine. ``closed_loop``: names of :data:`closed_loop_rows.CLOSED_LOOP` (the
    project's adaptive models with their own logic; adaptive rows only, at phase 0).
    ``probe_phases`` K: the adaptive mode of every model also at K - 1 further phases of its
    probing clock (:func:`thermal_eval.evaluate.adaptive.phase_budgets`); K = 1 is one run.
    ``load_probing``: every open-loop model's adaptive mode may also probe after machine-input
    steps from a token bucket, if its training-row walk-forward says so
    (:mod:`thermal_eval.evaluate.load_probing_choice`)."""
    budget = budget or ProbingBudget()
    phase_budgets(budget, probe_phases)          # a bad K is refused before any model runs
    engine = engine or EngineSpec()
    models = list(models) if models is not None else available_models(data)
    figures: dict[str, Any] = {"source": data.source, "rows": data.split.as_dict(), "n_rows": len(data),
                               "channels": data.channels, "temperatures": data.sensors, "inputs": data.input_names,
                               "notes": data.notes, "budget": budget.__dict__, "probe_phases": probe_phases,
                               "load_probing": load_probing,
                               "engine": engine.describe(),
                               "open_loop": {}, "adaptive": {}}
    result = EvaluationResult(figures)
    t0 = time.perf_counter()
    bad = [c for c in closed_loop if c not in CLOSED_LOOP]
    if bad:
        raise SpecError(f"--closed-loop: {bad[0]!r} is not a closed-loop model{closest(bad[0], list(CLOSED_LOOP))}")
    items: list = [m.name if REGISTRY.get(m.name) is m else m for m in models]
    items += [("closed_loop", c) for c in closed_loop] if adaptive else []
    rows: dict[int, ModelRow] = {}
    bar = tqdm(total=len(items), desc="evaluate", unit="model", disable=not show_progress)
    with bar, single_thread_blas(openmp=True):   # small dense problems: BLAS threads only contend
        for i, row in map_tasks(_row_task, (data, adaptive, budget, probe_phases, load_probing), items, engine):
            rows[i] = row
            bar.set_postfix_str(row.name)
            bar.update()
    for i in range(len(items)):
        _add_row(result, rows[i])
    _ratios_to_baseline(figures, data.channels)
    figures["seconds"] = round(time.perf_counter() - t0, 1)
    return result
