"""``evaluate`` on a data set of runs: every fold's training runs fit the models, every held-out
run is scored alone (its own start reference and probing clock), figures per run and pooled.

Per held-out run this is the single-recording evaluation of :func:`thermal_eval.evaluate.run.evaluate`
on :func:`thermal_eval.datasets.runs.fold_data` (the same models, baselines, adaptive mode and
holding beside it), with one difference: each model's ``select`` (the walk-forward choice of
inputs and hyper-parameters, most of the cost) runs once per fold on the training runs alone
(:class:`ChosenParams`), not once per held-out run; the refit, the out-of-fold prediction and
the adaptive mode run per held-out run. Held-out runs are the engine's tasks. Pooled figures put the residuals of every held-out run of a role
(validation / test) together: MAE, RMSE and P99 over all their rows; open-loop ratios against
the named baseline, adaptive ratios against holding the same probes, both on the same rows.

``truth`` (optional, per run: channel -> the noise-free displacement in the run's frame, e.g.
a twin fleet's): the same compensations are also scored against it (``vs_truth`` beside every
pooled figure): what the compensation leaves on the machine, without the noise of the reading
it is scored against. The models never see it: it enters after their predictions are made.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from thermal_comp_common.metrics import mae, p99, rmse
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_eval.datasets.run_start import RunStart, decide_run_start
from thermal_eval.datasets.runs import Run, fold_data, train_data
from thermal_comp_common.recording_sources import DatasetError
from thermal_comp_common.run_splits import RunFold
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.model_selection import ModelFailure, ModelSpec
from thermal_eval.evaluate.run import RATIO_BASELINE, REGISTRY, EvaluationResult, available_models, evaluate

FIGURES = (("mae_um", mae), ("rmse_um", rmse), ("p99_um", p99))


def _residuals(result: EvaluationResult, y: dict[str, np.ndarray], rows: slice,
               truth: dict[str, np.ndarray] | None = None) -> dict[str, dict]:
    """mode -> model -> channel -> residual on the held-out rows (open_loop, adaptive, hold).
    The held-out run starts at its own reference (row ``rows.start - 1``, displacement 0): an
    open-loop prediction is scored as its change since that row, as the run's displacement is.
    ``truth`` (channel -> array on the same rows as ``y``): the same residuals against it too,
    under ``truth`` (channels it lacks are left out there)."""
    out: dict[str, dict] = {"open_loop": {}, "adaptive": {}, "hold": {}}
    ref = rows.start - 1
    for mode, per in (("open_loop", result.open_loop), ("adaptive", result.adaptive), ("hold", result.hold)):
        for model, chans in per.items():
            out[mode][model] = {c: (y[c][rows] - (p[rows] - p[ref] if mode == "open_loop" else p[rows]))
                                for c, p in chans.items()}
    if truth is not None:
        # residual against the truth = residual against the recording + (truth - recording)
        gap = {c: truth[c][rows] - y[c][rows] for c in y if c in truth}
        out["truth"] = {mode: {m: {c: r + gap[c] for c, r in chans.items() if c in gap} for m, chans in per.items()}
                        for mode, per in out.items()}
    return out


def _aligned(truth: dict[str, np.ndarray] | None, n: int) -> dict[str, np.ndarray] | None:
    """A held-out run's truth placed on the last rows of its fold's data (where the run is)."""
    if truth is None:
        return None
    out = {}
    for c, v in truth.items():
        full = np.full(n, np.nan)
        full[n - len(v):] = v
        out[c] = full
    return out


def _figures(r: np.ndarray) -> dict[str, float | None]:
    r = r[np.isfinite(r)]
    return {k: (round(f(r, np.zeros_like(r)), 3) if r.size else None) for k, f in FIGURES} | {"n_rows": int(r.size)}


def pooled(residuals: Sequence[dict[str, dict]]) -> dict[str, Any]:
    """Residuals of several held-out runs pooled: mode -> model -> channel -> MAE, RMSE, P99,
    with the open loop's ratio to :data:`RATIO_BASELINE` and the adaptive ratio to holding the
    same probes (both MAE over MAE on the same rows); ``vs_truth``: the same figures against the
    truth when every run has one."""
    out: dict[str, Any] = {"open_loop": {}, "adaptive": {}}
    for mode in out:
        models = dict.fromkeys(m for r in residuals for m in r[mode])
        for m in models:
            chans = dict.fromkeys(c for r in residuals for c in r[mode].get(m, {}))
            cells = {}
            for c in chans:
                parts = [r[mode][m][c] for r in residuals if c in r[mode].get(m, {})]
                cell = _figures(np.concatenate(parts)) | {"runs": len(parts)}
                if mode == "adaptive":
                    h = _figures(np.concatenate([r["hold"][m][c] for r in residuals if c in r["hold"].get(m, {})]))
                    cell |= {f"hold_own_probes_{k}": h[k] for k in ("mae_um", "rmse_um", "p99_um")}
                    cell["ratio_to_hold"] = _ratio(cell["mae_um"], h["mae_um"])
                cells[c] = cell
            out[mode][m] = cells
    base = out["open_loop"].get(RATIO_BASELINE, {})
    for m, cells in out["open_loop"].items():
        for c, cell in cells.items():
            cell[f"ratio_to_{RATIO_BASELINE}"] = _ratio(cell["mae_um"], base.get(c, {}).get("mae_um"))
    if residuals and all("truth" in r for r in residuals):
        out["vs_truth"] = pooled([r["truth"] for r in residuals])
    return out


def _ratio(a, b) -> float | None:
    return round(a / b, 3) if a is not None and b else None


def _checked_truth(runs: Sequence[Run], truth) -> tuple | None:
    """The truth per run, each array as long as its run and on channels the run has."""
    if truth is None:
        return None
    if len(truth) != len(runs):
        raise DatasetError(f"truth: {len(truth)} entries for {len(runs)} runs")
    out = []
    for run, t in zip(runs, truth):
        if t is not None:
            t = {c: np.asarray(v, float) for c, v in t.items()}
            for c, v in t.items():
                if c not in run.data.displacement_um or v.shape != (len(run.data),):
                    raise DatasetError(f"{run.entry.path}: truth channel {c!r} with shape {v.shape}: the run has "
                                       f"{len(run.data)} rows on channels {list(run.data.displacement_um)[:8]}")
        out.append(t)
    return tuple(out)


def _run_info(run: Run) -> dict[str, Any]:
    e = run.entry
    return {"name": e.name, "path": e.path, "unit": e.unit, "programme": e.programme, "date": e.date,
            "hall_setpoint_c": e.hall_setpoint_c, "rows": len(run.data), "hours": round(run.hours, 3)}


@dataclass(frozen=True)
class ChosenParams:
    """A model's ``select`` replaced by what it chose once on a fold's training runs: per
    channel the parameters, or the reason it failed (raised again, so the cell fails the same way)."""

    by_channel: dict

    def __call__(self, data, channel: str, n_fit: int) -> dict:
        p = self.by_channel[channel]
        if isinstance(p, str):
            raise ModelFailure(p)
        return p


def _select_task(shared: tuple, name: str) -> dict:
    """Task: one model's choice on every channel of the training runs."""
    data, specs = shared
    model = specs.get(name) or REGISTRY[name]
    out = {}
    for ch in data.channels:
        try:
            out[ch] = model.select(data, ch, len(data))
        except Exception as exc:   # one failing channel is one failed cell in every held-out run
            out[ch] = f"select on the training runs: {type(exc).__name__}: {exc}"[:300]
    return out


def _held_out_task(shared: tuple, item: tuple[str, int]) -> dict:
    """Task: one held-out run scored with the fold's choices; its residuals and figures."""
    runs, train, chosen, specs, adaptive, budget, closed_loop, probe_phases, rest_h, from_start, truth = shared
    role, i = item
    data = fold_data(runs, train, i, rest_h, from_start)
    models = [replace(specs.get(n) or REGISTRY[n], select=ChosenParams(chosen[n])) for n in chosen]
    res = evaluate(data, models=models, adaptive=adaptive, budget=budget, closed_loop=closed_loop,
                   probe_phases=probe_phases, show_progress=False)
    t = _aligned(truth[i], len(data)) if truth is not None else None
    return {"role": role, "run": i, "residuals": _residuals(res, data.displacement_um, data.split.test, t),
            "seconds": res.figures["seconds"], "notes": data.notes}


def _choose(runs: Sequence[Run], fold: RunFold, models: Sequence[ModelSpec], engine: EngineSpec,
            rest_h: float = 0.0, from_start: bool = False) -> dict:
    data = train_data(runs, fold.train, rest_h, from_start)
    specs = {m.name: m for m in models if REGISTRY.get(m.name) is not m}
    chosen: dict[int, dict] = {}
    with single_thread_blas(openmp=True):
        for k, sel in map_tasks(_select_task, (data, specs), [m.name for m in models], engine):
            chosen[k] = sel
    return {m.name: chosen[k] for k, m in enumerate(models)}


def evaluate_runs(runs: Sequence[Run], folds: Sequence[RunFold], *, models: Sequence[ModelSpec] | None = None,
                  adaptive: bool = True, budget: ProbingBudget | None = None, engine: EngineSpec | None = None,
                  closed_loop: Sequence[str] = (), probe_phases: int = 1, run_start: str | RunStart = "auto",
                  rest_h: float | None = None, progress: Callable[[str], None] | None = None,
                  truth: Sequence[dict[str, np.ndarray] | None] | None = None) -> dict[str, Any]:
    """Every fold, every held-out run: its figures alone; pooled per role per fold and over every
    fold (``pooled``: every held-out run of a role once per fold it is held out in). ``run_start``
    (auto / continued / separate, or a decided :class:`RunStart`) and ``rest_h`` say how the runs
    are laid end to end (:func:`thermal_eval.datasets.run_start.decide_run_start`: auto decides from
    the temperatures where one run ends and the next starts); the decision is in ``run_start``.
    ``truth``: per run (same order as ``runs``) channel -> noise-free displacement on its rows
    in its frame, or None; held-out runs with one are also scored against it (``vs_truth``)."""
    t0 = time.perf_counter()
    say = progress or (lambda s: print(s, file=sys.stderr, flush=True))
    start = run_start if isinstance(run_start, RunStart) else decide_run_start(runs, run_start, rest_h)
    rest_h, temperatures_from_start = start.rest_h, start.temperatures_from_start
    say(f"evaluate runs: {start.describe()}")
    engine = engine or EngineSpec()
    models = list(models) if models is not None else available_models(runs[0].data)
    budget = budget or ProbingBudget()
    truth = _checked_truth(runs, truth)
    figures: dict[str, Any] = {"runs": [_run_info(r) for r in runs], "ratio_baseline": RATIO_BASELINE,
                               "budget": budget.__dict__, "engine": engine.describe(), "rest_h": rest_h,
                               "temperatures_from_start": temperatures_from_start, "run_start": start.as_dict(),
                               "folds": []}
    total = sum(len(f.held_out()) for f in folds)
    done = 0
    every: dict[str, list] = {"validation": [], "test": []}
    for fold in folds:
        t1 = time.perf_counter()
        chosen = _choose(runs, fold, models, engine, rest_h, temperatures_from_start)
        say(f"evaluate runs: fold {fold.name}: models chosen on {len(fold.train)} training runs "
            f"({time.perf_counter() - t1:.1f} s)")
        specs = {m.name: m for m in models if REGISTRY.get(m.name) is not m}
        shared = (runs, tuple(fold.train), chosen, specs, adaptive, budget, tuple(closed_loop), probe_phases, rest_h,
                  temperatures_from_start, truth)
        items = fold.held_out()
        per_run, resid = [None] * len(items), {"validation": [], "test": []}
        out: dict[int, dict] = {}
        with single_thread_blas(openmp=True):
            for k, r in map_tasks(_held_out_task, shared, items, engine):
                out[k] = r
                done += 1
                say(f"evaluate runs: {done}/{total} run {runs[r['run']].entry.name!r} ({r['role']}, fold {fold.name}) "
                    f"{r['seconds']:.1f} s")
        for k in range(len(items)):
            r = out[k]
            e = runs[r["run"]].entry
            resid[r["role"]].append(r["residuals"])
            every[r["role"]].append(r["residuals"])
            per_run[k] = {"run": e.name, "role": r["role"], "unit": e.unit, "programme": e.programme,
                          "pooled": pooled([r["residuals"]]), "seconds": r["seconds"], "notes": r["notes"]}
        figures["folds"].append({"name": fold.name, "train": [runs[i].entry.name for i in fold.train],
                                 "per_run": per_run, "pooled": {role: pooled(v) for role, v in resid.items() if v}})
    figures["pooled"] = {role: pooled(v) for role, v in every.items() if v}
    figures["seconds"] = round(time.perf_counter() - t0, 1)
    return figures
