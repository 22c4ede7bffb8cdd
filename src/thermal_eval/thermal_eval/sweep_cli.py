"""``thermal-comp sweep REC --out DIR [--jobs N] [--engine dask --address tcp://HOST:8786] [--limit N] ...``

TALC over the Blaser thesis's Table 6.1 grid (2,191 combinations per load case, see
``thermal_eval.sweep``) on one recording, in parallel with a progress bar: on a local process
pool (default) or on a Dask cluster (``--engine dask``; docs/distributed.md). Writes
``DIR/results.jsonl`` (one line per combination; rerun the same command to resume),
``DIR/table.csv`` (sorted by P99_lin; probe-and-hold at each row's Q_prod beside it), ``DIR/best.json`` (lowest P99_lin with Q_prod >= 95 %)
and the plots ``DIR/p99_vs_qprod.png`` (Fig. 6.9) and ``DIR/qprod_vs_p99_limit.png`` (Fig. 6.10).
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

from thermal_comp_common.engine_options import add_engine_arguments, engine_from_args
from thermal_comp_common.task_engine import TaskEngineError, default_workers

from thermal_eval.replay_summary import (PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM,
                             ReplayInputError, build_model, load_config_file, load_replay_recording,
                             parse_overrides)
from thermal_eval.sweep import (Q_PROD_MIN_PCT, TALC_INPUTS, SweepError, SweepRun, best_under_constraint,
                    format_probe_and_hold, parse_grid_subset, plot_sweep, run_sweep, seconds_per_combination, select_points, table_6_1_grid, write_table)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp sweep", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", metavar="REC", help="twin CSV, bag folder or .mcap file (one load case)")
    ap.add_argument("--out", required=True, metavar="DIR", help="folder for results.jsonl, table, plots")
    add_engine_arguments(ap, default_jobs=default_workers(), what="replays")
    ap.add_argument("--limit", type=int, default=None, help="only N combinations, spread evenly over the grid")
    ap.add_argument("--grid-subset", default="", metavar="SPEC",
                    help="restrict the grid, e.g. 'cp_length_h=8.5,12;post_cp_interval_h=2,10'; "
                         "update_interval_h=8,24 sweeps that parameter too")
    ap.add_argument("--update-interval-h", type=float, default=24.0,
                    help="update interval held for the grid (default %(default)s h, Table 6.4)")
    ap.add_argument("--config", metavar="YAML", help="base TALC parameters (the grid's five override them)")
    ap.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                    help="override one base parameter; repeatable")
    ap.add_argument("--q-prod-min", type=float, default=Q_PROD_MIN_PCT, help="Q_prod constraint, %% (default 95)")
    ap.add_argument("--probe-noise-um", type=float, default=PROBE_NOISE_LINEAR_UM)
    ap.add_argument("--probe-noise-um-per-m", type=float, default=PROBE_NOISE_ANGULAR_UM_PER_M)
    ap.add_argument("--probe-resolution-um", type=float, default=PROBE_RESOLUTION_UM)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-progress", action="store_true")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
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
        rec = load_replay_recording(args.recording)
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


if __name__ == "__main__":
    sys.exit(main())
