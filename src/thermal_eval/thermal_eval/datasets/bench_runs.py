"""The data-set figures of ``thermal-comp bench evaluate``: a twin-made fleet scored on unseen
runs and an unseen unit (against its noisy recording and against the twin's noise-free truth), FL_THERMAL cut into runs beside its single-recording figures, and the
wall time of ``evaluate`` on many runs."""
from __future__ import annotations

import pathlib
import tempfile
import time
from typing import Any

import numpy as np

from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_eval.datasets.evaluate_runs import evaluate_runs
from thermal_eval.datasets.fleet import FleetPlan, load_truth, unseen_fold, write_fleet
from thermal_eval.datasets.report_runs import fleet_markdown, print_runs
from thermal_eval.datasets.runs import Run, load_runs, segments
from thermal_comp_common.recording_sources import RunEntry, resolve_runs
from thermal_comp_common.run_splits import RunFold, run_splits
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.spec import FL_THERMAL_SPEC, load_evaluation_data

#: one probing per hour, scheduled, and never more on average
HOURLY = ProbingBudget(probe_every_h=1.0, max_probes_per_h=1.0)
ROLE_NAMES = {"validation": "unseen_runs", "test": "unseen_unit"}


def summary(pooled: dict[str, Any], base: str) -> dict[str, Any]:
    """Per model: channel-mean MAE and the worst channel's ratio (open loop: to ``base``;
    adaptive: to holding the same probes); ``vs_truth``: the same against the truth when the
    pooled figures have it."""
    out: dict[str, Any] = {"open_loop": {}, "adaptive": {}}
    if "vs_truth" in pooled:
        out["vs_truth"] = summary(pooled["vs_truth"], base)
    for name, cells in pooled["open_loop"].items():
        r = [c[f"ratio_to_{base}"] for c in cells.values() if c.get(f"ratio_to_{base}") is not None]
        out["open_loop"][name] = {"mean_mae_um": round(float(np.mean([c["mae_um"] for c in cells.values()])), 3),
                                  f"worst_channel_ratio_to_{base}": max(r) if r else None}
    for name, cells in pooled["adaptive"].items():
        r = [c["ratio_to_hold"] for c in cells.values() if c.get("ratio_to_hold") is not None]
        out["adaptive"][name] = {"mean_mae_um": round(float(np.mean([c["mae_um"] for c in cells.values()])), 3),
                                 "hold_mean_mae_um": round(float(np.mean([c["hold_own_probes_mae_um"]
                                                                          for c in cells.values()])), 3),
                                 "worst_channel_ratio_to_hold": max(r) if r else None,
                                 "at_most_half_of_holding": bool(r) and max(r) <= 0.5}
    return out


def worst_run_ratio(figures: dict[str, Any], vs_truth: bool = False) -> dict[str, dict[str, float]]:
    """Per adaptive model and role: the largest ratio to holding of any held-out run and channel
    (``vs_truth``: both scored against the truth)."""
    out: dict[str, dict[str, float]] = {}
    for fold in figures["folds"]:
        for r in fold["per_run"]:
            p = r["pooled"].get("vs_truth", {}) if vs_truth else r["pooled"]
            for name, cells in p.get("adaptive", {}).items():
                v = [c["ratio_to_hold"] for c in cells.values() if c.get("ratio_to_hold") is not None]
                if v:
                    d = out.setdefault(name, {})
                    role = ROLE_NAMES.get(r["role"], r["role"])
                    d[role] = max(d.get(role, 0.0), max(v))
    return out


def run_fleet(engine: EngineSpec, quick: bool = False, presets=("spindle-stand", "swiss-lathe"),
              rest_h: float | None = None, seed: int = 0, run_start: str = "auto") -> dict[str, Any]:
    """Per preset: 4 units x 5 runs of 5 h (quick: 3 units x 3 runs of 3 h); units 0..2 train on
    their first 3 runs (quick: 2), scored on their other runs and on every run of the last unit.
    ``run_start`` / ``rest_h``: ``evaluate --run-start / --rest-h`` (default: decided from the
    data). ``seed``: the fleet's (its units and runs: :class:`FleetPlan`)."""
    out: dict[str, Any] = {}
    for preset in presets:
        plan = FleetPlan(preset, units=3, runs_per_unit=3, hours=3.0, seed=seed) if quick else \
            FleetPlan(preset, seed=seed)
        train_per_unit = 2 if quick else 3
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            runs = load_runs(resolve_runs([str(write_fleet(plan, pathlib.Path(d) / preset))]))
            made = time.perf_counter() - t0
            fold = unseen_fold(plan, train_per_unit)
            truth = [load_truth(r) for r in runs]
            f = evaluate_runs(runs, [fold], budget=HOURLY, engine=engine, run_start=run_start, rest_h=rest_h,
                              truth=truth)
        print(f"fleet {preset}: {len(runs)} runs (units x runs {plan.units} x {plan.runs_per_unit}, {plan.hours:g} h, "
              f"probe noise {plan.probe_noise_um} um); validation = unseen runs of U0-U{plan.units - 2}, "
              f"test = every run of unseen unit U{plan.units - 1}")
        print_runs(f)
        base = f["ratio_baseline"]
        out[preset] = {"plan": plan.__dict__, "run_start": f["run_start"],
                       "simulate_seconds": round(made, 1), "seconds": f["seconds"],
                       **{ROLE_NAMES[k]: summary(v, base) for k, v in f["pooled"].items()},
                       "worst_run_ratio_to_hold": worst_run_ratio(f),
                       "worst_run_ratio_to_hold_vs_truth": worst_run_ratio(f, vs_truth=True), "evaluation": f}
        print(fleet_markdown(preset, out[preset], seed))
    return out


def run_fl_segments(csv: str, k: int, engine: EngineSpec, every: int = 1) -> dict[str, Any]:
    """FL_THERMAL cut into ``k`` runs (each its own start reference and probing clock): with
    k = 5 the first three train, the fourth is the test run and the fifth the validation run,
    the rows of the authors' split; figures to print beside the single-recording ones."""
    data = load_evaluation_data(csv, {kk: v for kk, v in FL_THERMAL_SPEC.items() if kk != "split"}, whole=True)
    if every > 1:
        idx = np.arange(0, len(data), every)
        data.time_s, data.temperatures = data.time_s[idx], data.temperatures[idx]
        data.inputs = None if data.inputs is None else data.inputs[idx]
        data.displacement_um = {c: v[idx] for c, v in data.displacement_um.items()}
        data.split.n_train = data.split.n = idx.size
    parts = segments(Run(RunEntry(csv, "FL_THERMAL"), data), k)
    n_train = int(round(0.6 * k))
    fold = RunFold(f"segments 1-{n_train} train", tuple(range(n_train)), tuple(range(n_train + 1, k)), (n_train,))
    f = evaluate_runs(parts, [fold], budget=ProbingBudget(probe_every_h=2.0, max_probes_per_h=1.0), engine=engine)
    print(f"FL_THERMAL cut into {k} runs: segments 1-{n_train} train, segment {n_train + 1} test, the rest validation")
    print_runs(f)
    return f


def beside(single: dict[str, Any], runs: dict[str, Any]) -> dict[str, Any]:
    """Test-row MAE per model and channel: the single recording (time split) beside the
    cross-run figures (its rows cut into runs)."""
    out = {}
    pooled = runs["pooled"]["test"]
    for mode in ("open_loop", "adaptive"):
        for name, row in single[mode].items():
            if "failed" in row or name not in pooled[mode]:
                continue
            out[f"{mode}.{name}"] = {ch: {"single_recording": c.get("mae_test_um"),
                                          "cut_into_runs": pooled[mode][name].get(ch, {}).get("mae_um")}
                                     for ch, c in row["channels"].items()}
    return out


def run_timing(n_runs: int, engine: EngineSpec, preset: str = "swiss-lathe") -> dict[str, Any]:
    """Wall time of the data-set evaluation of ``n_runs`` twin runs of 5 h (default split by
    run, every default model, adaptive at the default budget)."""
    units = max(1, n_runs // 5)
    plan = FleetPlan(preset, units=units, runs_per_unit=int(np.ceil(n_runs / units)), seed=1)
    with tempfile.TemporaryDirectory() as d:
        entries = resolve_runs([str(write_fleet(plan, pathlib.Path(d) / "runs"))])[:n_runs]
        t0 = time.perf_counter()
        runs = load_runs(entries)
        folds = run_splits([r.entry for r in runs])
        f = evaluate_runs(runs, folds, engine=engine)
        wall = time.perf_counter() - t0
    held = sum(len(x.held_out()) for x in folds)
    print(f"evaluate on {len(runs)} recordings of {plan.hours:g} h ({held} held out, {engine.describe()}): "
          f"{wall:.1f} s wall (target < 300 s)")
    return {"runs": len(runs), "hours_each": plan.hours, "held_out": held, "wall_seconds": round(wall, 1),
            "under_5_min": wall < 300.0, "engine": engine.describe()}
