"""``learn`` on a split of several folds (``loro``, ``by:FIELD``): one learning per fold, each
scored on the runs it held out, those figures pooled over the folds; the unit twin written is
one more learning on every run (the folds measured how such a learning does on runs it has not
seen; its own adoption is decided on the last quarter of every run, or ``--validate-h``), as
``calibrate --runs-split`` writes its all-runs fit. Pooled per predictor and component over the
held-out runs: RMSE as sqrt(sum n rmse^2 / sum n), MAE as the n-weighted mean (a P99 does not
pool from per-run figures). No rclpy.
"""
from __future__ import annotations

import json
import math
import pathlib
from typing import Any, Callable, Sequence

from thermal_comp_common.json_figures import finite_figures
from thermal_comp_common.run_splits import RunFold

from thermal_eval.learn.current import CurrentPrior
from thermal_eval.learn.runs.command import learn_runs
from thermal_eval.learn.runs.sources import CellRun


def pool_tables(tables: Sequence[dict]) -> dict[str, dict[str, dict[str, float]]]:
    """Score tables (predictor -> component -> rmse, mae, n) of disjoint probes pooled into one."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for table in tables:
        for name, row in table.items():
            for c, v in row.items():
                acc = out.setdefault(name, {}).setdefault(c, {"sse": 0.0, "sae": 0.0, "n": 0})
                if v["n"] and math.isfinite(v["rmse"]):
                    acc["sse"] += v["n"] * v["rmse"] ** 2
                    acc["sae"] += v["n"] * v["mae"]
                    acc["n"] += v["n"]
    return {name: {c: {"rmse": math.sqrt(a["sse"] / a["n"]) if a["n"] else math.nan,
                       "mae": a["sae"] / a["n"] if a["n"] else math.nan, "n": a["n"]} for c, a in row.items()}
            for name, row in out.items()}


def learn_folds(machine, runs: Sequence[CellRun], folds: Sequence[RunFold], out: pathlib.Path,
                validate_h: float | None = None, max_nfev: int = 20, progress: Callable[[str], None] = lambda m: None,
                build_priors: bool = True, current: CurrentPrior | None = None) -> dict[str, Any]:
    """One learning per fold (into ``out/folds/NN``), then the unit twin from every run (into
    ``out``); the report of the latter with ``folds`` and ``pooled_over_folds`` (module docstring)."""
    summaries, held = [], []
    for k, fold in enumerate(folds, 1):
        progress(f"fold {k}/{len(folds)} ({fold.name})")
        where = out / "folds" / f"{k:02d}"
        rep = learn_runs(machine, runs, fold, where, validate_h, max_nfev, progress, build_priors, current)
        tests = {runs[i].name for i in fold.test}
        scores = {n: t for n, t in rep["scores"]["per_run"].items() if n in tests}
        held += list(scores.values())
        summaries.append({"name": fold.name, "dir": str(where), "train": [runs[i].name for i in fold.train],
                          "test": sorted(tests), "adopt": rep["adoption"]["adopt"], "reason": rep["adoption"]["reason"],
                          "scores": scores})
    progress(f"all {len(runs)} runs: learning the unit twin written")
    every = RunFold("all runs", tuple(range(len(runs))), (), ())
    report = learn_runs(machine, runs, every, out, validate_h, max_nfev, progress, build_priors, current)
    report["folds"] = summaries
    report["pooled_over_folds"] = pool_tables(held)
    (out / "report.json").write_text(json.dumps(finite_figures(report), indent=1, allow_nan=False) + "\n")
    return report
