"""``thermal-comp bench evaluate``: the generic evaluation on FL_THERMAL and on a twin plateau.

Figures:

- ``fl_thermal.open_loop.<model>.<ch>``: test / validation MAE through the generic path (the
  FL_THERMAL spec of :mod:`thermal_eval.evaluate.spec`), beside today's figures of
  docs/fl_thermal.md (``reproduction``: relative difference, within 5 %?) and whether the
  open loop beats the published S2S2 on every channel;
- ``fl_thermal.adaptive.<model>``: MAE test / validation, holding the same probes, probings per
  hour after calibration, and whether the target (<= 1 um on every channel on both held-out
  windows and >= 30 % below holding) is met; ``best_adaptive`` names the best model;
- ``plateau``: a twin recording (spindle-stand, ISO 230-3: 4 h run, then 26 h stopped) whose
  held-out rows are a long steady state: adaptive MAE over holding (target <= 1.10);
- ``--probe-phases K``: FL_THERMAL's adaptive rows also scored with the probing clock delayed by
  i/K of the interval; ``adaptive_targets`` then says the target at phase 0 and on the phase mean;
- ``--load-probing``: FL_THERMAL's adaptive rows may also probe after spindle-speed steps
  (:mod:`talc_model.open_loop.load_probing`; ``--bucket-credit=0``: never above one per hour on average);
- ``*.seconds`` per model: what dominates the wall time (target < 300 s on FL_THERMAL).

- ``fl_thermal_runs``: FL_THERMAL cut into 5 runs (3 train, 1 test, 1 validation: the authors'
  rows), each with its own start reference and probing clock; ``fl_thermal_beside`` puts its
  test-run MAE beside the single recording's (:mod:`thermal_eval.datasets.bench_runs`);
- ``fleet``: a twin-made fleet per preset (4 units x 5 runs of 5 h, probe noise), trained on 3
  runs of 3 units, scored on their other runs and on the unseen unit, adaptive at one probing
  per hour beside holding; each figure against the noisy recording (what a real one gives) and,
  under ``vs_truth``, against the twin's noise-free displacement (the models' probes stay
  noisy); ``--timing-runs=40``: wall time of ``evaluate`` on 40 runs of 5 h.

``--quick``: every 4th FL_THERMAL row and a smaller fleet (a smoke run; its figures differ).
``--sections=fl_thermal,plateau,segments,fleet`` picks the parts (default: all of them).
"""
from __future__ import annotations

import argparse
import pathlib
import tempfile
import time
from typing import Any

import numpy as np

from thermal_comp_common.runtime.engine_options import add_jobs_argument
from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_eval.datasets.bench_runs import beside, run_fl_segments, run_fleet, run_timing
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.report import print_table
from thermal_eval.evaluate.run import evaluate
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM
from thermal_eval.evaluate.spec import FL_THERMAL_SPEC, EvaluationData, load_evaluation_data, make_split
from thermal_eval.fl_thermal.data import default_csv_path
from thermal_twin.sim.cli import main as sim_main

#: today's open-loop figures (test-row MAE, um) of docs/fl_thermal.md, by the generic name
TODAY_OPEN_LOOP_UM = {
    "arx_simulation": (1.061, 1.436, 1.952, 1.956, 2.493),
    "arx_simulation_inputs": (0.776, 0.783, 2.843, 1.989, 2.960),   # docs: arx_simulation_spindle
}
S2S2_UM = (3.561, 3.755, 3.704, 3.461, 4.284)
ADAPTIVE_TARGET_UM = 1.0
ADAPTIVE_GAIN_OVER_HOLD = 0.30
PLATEAU_TOLERANCE = 1.10


def thinned(data: EvaluationData, every: int, split: dict) -> EvaluationData:
    """Every ``every``-th row (the --quick smoke run), split again by the spec."""
    if every == 1:
        return data
    idx = np.arange(0, len(data), every)
    return EvaluationData(data.time_s[idx], data.temperatures[idx], data.sensors,
                          None if data.inputs is None else data.inputs[idx], data.input_names,
                          {k: v[idx] for k, v in data.displacement_um.items()}, make_split(idx.size, split),
                          data.source, data.notes)


def _reproduction(figures: dict) -> dict:
    out = {}
    for name, today in TODAY_OPEN_LOOP_UM.items():
        row = figures["open_loop"].get(name)
        if row is None:
            continue
        cells = [row["channels"][ch] for ch in figures["channels"]]
        rel = [round(c["mae_test_um"] / t - 1.0, 4) if "mae_test_um" in c else None for c, t in zip(cells, today)]
        out[name] = {"relative_difference": rel,
                     "within_5_pct": all(r is not None and abs(r) <= 0.05 for r in rel)}
    beats = {}
    for name, row in figures["open_loop"].items():
        if row["kind"] == "model":
            beats[name] = all(row["channels"][ch].get("mae_test_um", np.inf) < s
                              for ch, s in zip(figures["channels"], S2S2_UM))
    out["beats_s2s2_on_every_channel"] = beats
    return out


def _target(cells: list[dict], per_h: float) -> dict:
    """The adaptive target (docs/evaluate.md) on cells of MAE / holding's MAE (test and validation)."""
    worst = max(max(c["mae_test_um"], c["mae_validation_um"]) for c in cells)
    gain = min(min(1 - c["mae_test_um"] / c["hold_own_probes_mae_test_um"],
                   1 - c["mae_validation_um"] / c["hold_own_probes_mae_validation_um"]) for c in cells)
    return {"worst_channel_mae_um": round(worst, 3), "smallest_gain_over_hold": round(gain, 3),
            "probings_per_h": per_h,
            "meets_target": bool(worst <= ADAPTIVE_TARGET_UM and gain >= ADAPTIVE_GAIN_OVER_HOLD and per_h <= 1.0)}


def _adaptive_targets(figures: dict) -> dict:
    """Per adaptive row: the target at phase 0 (the budget's own schedule) and, when the rows
    were scored at several probe phases, on the phase-mean MAE (and holding's phase mean; the
    most probings per hour of any phase) and the worst phase's largest MAE."""
    out, best = {}, None
    for name, row in figures["adaptive"].items():
        if "failed" in row:
            continue
        cells = list(row["channels"].values())
        if any("failed" in c for c in cells):
            continue
        out[name] = _target(cells, row["probings_per_h_after_calibration"])
        if "probe_phases" in row:
            ph = row["probe_phases"]
            out[name]["phase_mean"] = {**_target([c["phases"]["mean"] for c in cells],
                                                 max(ph["probings_per_h_after_calibration"])), "phases": ph["k"]}
            out[name]["phase_mean"]["worst_phase_channel_mae_um"] = max(
                max(c["phases"]["worst"]["mae_test_um"], c["phases"]["worst"]["mae_validation_um"]) for c in cells)
        worst = out[name]["worst_channel_mae_um"]
        if best is None or worst < best[1]:
            best = (name, worst)
    out["best_adaptive"] = None if best is None else best[0]
    return out


def run_fl_thermal(csv: str | None, every: int, show_progress: bool, engine: EngineSpec | None = None,
                   probe_phases: int = 1, load_probing: bool = False, bucket_credit: float = 1.0) -> dict[str, Any]:
    t0 = time.perf_counter()
    data = thinned(load_evaluation_data(csv or default_csv_path(), FL_THERMAL_SPEC), every, FL_THERMAL_SPEC["split"])
    load_s = time.perf_counter() - t0
    budget = ProbingBudget(probe_every_h=2.0, max_probes_per_h=1.0, tolerance_um=1.0, bucket_credit=bucket_credit)
    result = evaluate(data, budget=budget,
                      show_progress=show_progress, engine=engine, probe_phases=probe_phases,
                      load_probing=load_probing)
    f = result.figures
    print_table(f)
    f["load_seconds"] = round(load_s, 1)
    f["reproduction"] = _reproduction(f)
    f["adaptive_targets"] = _adaptive_targets(f)
    f["seconds_by_model"] = {k: v["seconds"] for k, v in f["open_loop"].items()}
    f["every_nth_row"] = every
    return f


def run_plateau(show_progress: bool, engine: EngineSpec | None = None) -> dict[str, Any]:
    """Twin spindle stand, ISO 230-3 for 30 h: the held-out rows are a long steady state."""
    with tempfile.TemporaryDirectory() as d:
        path = pathlib.Path(d) / "plateau.csv"
        rc = sim_main(["--machine", "spindle-stand", "--scenario", "iso230-3", "--hours", "30", "--step", "60",
                       "--csv", str(path), "--quiet"])
        if rc != 0:
            return {"failed": f"thermal-comp sim exited with {rc}"}
        data = load_evaluation_data(path, {"inputs": []})
    # the twin's displacements are noise-free: a probe reads them no better than the project's
    # sphere cycle (thesis Table 5.4, the replay's probe), so its resolution is the dead band
    result = evaluate(data, budget=ProbingBudget(probe_resolution_um=PROBE_RESOLUTION_UM),
                      show_progress=show_progress, engine=engine)
    f = result.figures
    ratios = {}
    for name, row in f["adaptive"].items():
        if "failed" not in row:
            ratios[name] = max(max(c.get("ratio_to_hold_test") or 0.0, c.get("ratio_to_hold_validation") or 0.0)
                               for c in row["channels"].values() if "failed" not in c)
    excess = {name: round(max(max(c["mae_test_um"] - c["hold_own_probes_mae_test_um"],
                                  c["mae_validation_um"] - c["hold_own_probes_mae_validation_um"])
                              for c in row["channels"].values() if "failed" not in c), 4)
              for name, row in f["adaptive"].items() if "failed" not in row}
    return {"worst_ratio_to_hold_by_model": ratios, "worst_excess_over_hold_um": excess,
            "within_10_pct_of_hold": {k: bool(v <= PLATEAU_TOLERANCE) for k, v in ratios.items()},
            "hold_mae_test_um": {ch: c["hold_own_probes_mae_test_um"] for ch, c in
                                 next(iter(f["adaptive"].values()))["channels"].items() if "failed" not in c},
            "seconds": f["seconds"], "evaluation": f}


def parser() -> argparse.ArgumentParser:
    """The suite's options (after ``--``)."""
    ap = argparse.ArgumentParser(prog="thermal-comp bench evaluate")
    ap.add_argument("--csv", default=None, help="FL_THERMAL CSV (default: $THERMAL_COMP_SHARED/data/fl_thermal)")
    ap.add_argument("--no-plateau", action="store_true")
    add_jobs_argument(ap, "model rows")
    ap.add_argument("--probe-phases", type=int, default=1, metavar="K",
                    help="FL_THERMAL's adaptive rows also at K phases of the probing clock (mean and worst)")
    ap.add_argument("--load-probing", action="store_true",
                    help="FL_THERMAL's adaptive rows may also probe after spindle-speed steps (token bucket; "
                         "chosen per model on the training rows)")
    ap.add_argument("--bucket-credit", type=float, default=1.0, choices=(0.0, 1.0),
                    help="with --load-probing: probings the bucket holds when calibration ends (0: never above "
                         "one per hour on average)")
    ap.add_argument("--sections", default="fl_thermal,plateau,segments,fleet",
                    help="comma-separated parts: fl_thermal, plateau, segments (FL_THERMAL cut into runs), fleet")
    ap.add_argument("--rest-h", type=float, default=None, metavar="H",
                    help="fleet: every run preceded by its first reading held H hours (evaluate --rest-h)")
    ap.add_argument("--run-start", choices=("auto", "continued", "separate"), default="auto",
                    help="fleet: evaluate --run-start (default auto: decided from the data)")
    ap.add_argument("--fleet-seed", type=int, default=0, metavar="S", help="fleet: the fleet's seed (default 0)")
    ap.add_argument("--timing-runs", type=int, default=0, metavar="N",
                    help="also time evaluate on N twin runs of 5 h (default 0: off)")
    return ap


def run(args: argparse.Namespace) -> dict[str, Any]:
    opts = parser().parse_args([e for e in (getattr(args, "extra", None) or []) if e != "--"])
    sections = set(opts.sections.split(","))
    every = 4 if getattr(args, "quick", False) else 1
    t0 = time.perf_counter()
    engine = EngineSpec("local", workers=opts.jobs)
    figures: dict[str, Any] = {"engine": engine.describe()}
    if "fl_thermal" in sections:
        figures["fl_thermal"] = run_fl_thermal(opts.csv, every, show_progress=True, engine=engine,
                                               probe_phases=opts.probe_phases, load_probing=opts.load_probing,
                                               bucket_credit=opts.bucket_credit)
        figures["fl_thermal_seconds"] = round(time.perf_counter() - t0, 1)
    if "plateau" in sections and not opts.no_plateau:
        figures["plateau"] = run_plateau(show_progress=True, engine=engine)
    if "segments" in sections:
        figures["fl_thermal_runs"] = run_fl_segments(opts.csv or str(default_csv_path()), 5, engine, every)
        if "fl_thermal" in figures:
            figures["fl_thermal_beside"] = beside(figures["fl_thermal"], figures["fl_thermal_runs"])
            for k, v in figures["fl_thermal_beside"].items():
                print(f"{k}: test MAE (um) single recording -> cut into runs: " + ", ".join(
                    f"{ch} {c['single_recording']} -> {c['cut_into_runs']}" for ch, c in v.items()))
    if "fleet" in sections:
        figures["fleet"] = run_fleet(engine, quick=every > 1, rest_h=opts.rest_h, seed=opts.fleet_seed,
                                     run_start=opts.run_start)
    if opts.timing_runs:
        figures["timing"] = run_timing(opts.timing_runs, engine)
    return figures
