"""The work of ``thermal-comp sweep`` (:mod:`thermal_eval.sweep.cli` parses the arguments): TALC over
the Table 6.1 grid on one recording, resumable, then the table, the best combination and the plots."""
from __future__ import annotations

import json
import math
import pathlib
import sys
import time

from thermal_comp_common.bags.truncation import truncated_bags_allowed
from thermal_comp_common.runtime.engine_options import engine_from_args
from thermal_comp_common.runtime.task_engine import TaskEngineError

from thermal_eval.replay.summary import (ReplayInputError, build_model, load_config_file, load_replay_recording,
                                         parse_overrides)
from thermal_eval.sweep.grid import (TALC_INPUTS, SweepError, SweepRun, best_under_constraint, format_probe_and_hold,
                                     parse_grid_subset, plot_sweep, run_sweep, seconds_per_combination, select_points,
                                     table_6_1_grid, write_table)


def run(args) -> int:
    """Sweep as the parsed arguments say; the exit code (0 done, 2 bad input)."""
    out = pathlib.Path(args.out)
    try:
        if not (math.isfinite(args.update_interval_h) or math.isinf(args.update_interval_h)) \
                or args.update_interval_h <= 0:
            raise SweepError(f"--update-interval-h: {args.update_interval_h!r} must be > 0 (or inf)")
        engine = engine_from_args(args)
        base = {"input_names": list(TALC_INPUTS)}
        if args.config:
            base.update(load_config_file(args.config))
        base.update(parse_overrides(args.overrides))
        build_model("talc", base)                     # validate the base configuration up front
        points = select_points(table_6_1_grid(args.update_interval_h),
                               parse_grid_subset(args.grid_subset), args.limit)
        if not points:
            raise SweepError(f"--grid-subset {args.grid_subset!r}: selects no combination of the grid")
        with truncated_bags_allowed(args.allow_truncated):     # read in this process only
            rec = load_replay_recording(args.recording, sample_period_s=args.sample_period_s)
        for w in rec.warnings:                                 # what was used is said before the work
            print(f"warning: {w}", file=sys.stderr)
        run = SweepRun("talc", base, args.probe_noise_um, args.probe_noise_um_per_m, args.probe_resolution_um,
                       args.seed, str(pathlib.Path(args.recording).resolve()))
        t0 = time.perf_counter()
        res = run_sweep(rec, run, points, out / "results.jsonl", jobs=args.jobs, progress=not args.no_progress,
                        engine=engine)
        wall = time.perf_counter() - t0
    except (ReplayInputError, ValueError, TaskEngineError) as exc:
        print(f"thermal-comp sweep: {exc}", file=sys.stderr)
        return 2
    for w in res["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    rows = res["rows"]
    write_table(rows, out / "table.csv")
    plots = plot_sweep(rows, out, title=pathlib.Path(args.recording).stem, q_prod_min_pct=args.q_prod_min)
    best = best_under_constraint(rows, args.q_prod_min)
    spc = seconds_per_combination(rows)
    summary = {"recording": args.recording, "combinations": len(rows), "computed": res["computed"],
               "resumed": res["skipped"], "seconds_per_combination": spc, "jobs": args.jobs,
               "engine": engine.describe(),
               "wall_s_this_run": round(wall, 1),
               "q_prod_min_pct": args.q_prod_min, "best": best}
    (out / "best.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    print(f"{len(rows)} combinations ({res['computed']} computed, {res['skipped']} from the results file), "
          f"median {spc:.1f} s per combination; this run {wall:.0f} s wall on {engine.describe()}")
    if best is None:
        print(f"no combination reaches Q_prod >= {args.q_prod_min:g} %")
    else:
        p = best["params"]
        print(f"best with Q_prod >= {args.q_prod_min:g} %: P99_lin {best['p99_lin_um']:.2f} um, "
              f"Q_prod {best['q_prod_pct']:.2f} % (CP {p['cp_length_h']:g} h, post-CP {p['post_cp_interval_h']:g} h, "
              f"NG {p['ng_measurements']:g} x {p['ng_interval_min']:g} min, update {p['update_interval_h']:g} h)")
        print(format_probe_and_hold(best))
    print(f"wrote {out / 'results.jsonl'}, {out / 'table.csv'}, {out / 'best.json'}, "
          + ", ".join(str(p) for p in plots))
    return 0
