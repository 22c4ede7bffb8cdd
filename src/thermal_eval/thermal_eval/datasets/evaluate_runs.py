"""``evaluate`` on a data set of runs: every fold's training runs fit the models, every held-out
run is scored alone (its own start reference and probing clock), figures per run and pooled.

Per held-out run this is the single-recording evaluation of :func:`thermal_eval.evaluate.run.evaluate`
on :func:`thermal_eval.datasets.runs.fold_data` (the same models, baselines, adaptive mode and
holding beside it). Pooled figures put the residuals of every held-out run of a role
(validation / test) together: MAE, RMSE and P99 over all their rows; open-loop ratios against
the named baseline, adaptive ratios against holding the same probes, both on the same rows.
"""
from __future__ import annotations

import sys
import time
from typing import Any, Callable, Sequence

import numpy as np

from thermal_comp_common.metrics import mae, p99, rmse
from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_eval.datasets.runs import Run, fold_data
from thermal_eval.datasets.splits import RunFold
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.model_selection import ModelSpec
from thermal_eval.evaluate.run import RATIO_BASELINE, EvaluationResult, evaluate

FIGURES = (("mae_um", mae), ("rmse_um", rmse), ("p99_um", p99))


def _residuals(result: EvaluationResult, y: dict[str, np.ndarray], rows: slice) -> dict[str, dict]:
    """mode -> model -> channel -> residual on the held-out rows (open_loop, adaptive, hold)."""
    out: dict[str, dict] = {"open_loop": {}, "adaptive": {}, "hold": {}}
    for mode, per in (("open_loop", result.open_loop), ("adaptive", result.adaptive), ("hold", result.hold)):
        for model, chans in per.items():
            out[mode][model] = {c: (y[c][rows] - p[rows]) for c, p in chans.items()}
    return out


def _figures(r: np.ndarray) -> dict[str, float | None]:
    r = r[np.isfinite(r)]
    return {k: (round(f(r, np.zeros_like(r)), 3) if r.size else None) for k, f in FIGURES} | {"n_rows": int(r.size)}


def pooled(residuals: Sequence[dict[str, dict]]) -> dict[str, Any]:
    """Residuals of several held-out runs pooled: mode -> model -> channel -> MAE, RMSE, P99,
    with the open loop's ratio to :data:`RATIO_BASELINE` and the adaptive ratio to holding the
    same probes (both MAE over MAE on the same rows)."""
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
    return out


def _ratio(a, b) -> float | None:
    return round(a / b, 3) if a is not None and b else None


def _run_info(run: Run) -> dict[str, Any]:
    e = run.entry
    return {"name": e.name, "path": e.path, "unit": e.unit, "programme": e.programme, "date": e.date,
            "hall_setpoint_c": e.hall_setpoint_c, "rows": len(run.data), "hours": round(run.hours, 3)}


def evaluate_runs(runs: Sequence[Run], folds: Sequence[RunFold], *, models: Sequence[ModelSpec] | None = None,
                  adaptive: bool = True, budget: ProbingBudget | None = None, engine: EngineSpec | None = None,
                  closed_loop: Sequence[str] = (), probe_phases: int = 1, show_progress: bool = False,
                  progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every fold, every held-out run: its figures alone; pooled per role per fold and over every
    fold (``pooled``: every held-out run of a role once per fold it is held out in)."""
    t0 = time.perf_counter()
    say = progress or (lambda s: print(s, file=sys.stderr, flush=True))
    figures: dict[str, Any] = {"runs": [_run_info(r) for r in runs], "ratio_baseline": RATIO_BASELINE,
                               "budget": (budget or ProbingBudget()).__dict__, "folds": []}
    total = sum(len(f.held_out()) for f in folds)
    done = 0
    every: dict[str, list] = {"validation": [], "test": []}
    for fold in folds:
        per_run, resid = [], {"validation": [], "test": []}
        for role, i in fold.held_out():
            data = fold_data(runs, fold.train, i)
            t1 = time.perf_counter()
            res = evaluate(data, models=models, adaptive=adaptive, budget=budget, engine=engine,
                           closed_loop=closed_loop, probe_phases=probe_phases, show_progress=show_progress)
            done += 1
            say(f"evaluate runs: {done}/{total} run {runs[i].entry.name!r} ({role}, fold {fold.name}) "
                f"{time.perf_counter() - t1:.1f} s")
            r = _residuals(res, data.displacement_um, data.split.test)
            resid[role].append(r)
            every[role].append(r)
            per_run.append({"run": runs[i].entry.name, "role": role, "unit": runs[i].entry.unit,
                            "programme": runs[i].entry.programme, "pooled": pooled([r]),
                            "seconds": res.figures["seconds"], "notes": data.notes})
        figures["folds"].append({"name": fold.name, "train": [runs[i].entry.name for i in fold.train],
                                 "per_run": per_run,
                                 "pooled": {role: pooled(v) for role, v in resid.items() if v}})
    figures["pooled"] = {role: pooled(v) for role, v in every.items() if v}
    figures["seconds"] = round(time.perf_counter() - t0, 1)
    return figures
