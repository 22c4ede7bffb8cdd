"""``thermal-comp bench models``: TALC parameter sweeps on the twin's load cases A-D (issue 6).

The full Table 6.1 grid (2,191 combinations per load case) takes hours per load case on this
2-core machine, so the benchmark runs a reduced, documented subset per load case and
extrapolates the full-grid time from the measured time per combination.

Subset (not tuned on our data): the four recommended sets of the thesis (Table 6.3, one per
load case there), each tried on every load case with update interval 24 h: 4 combinations of
the 2,191 per load case, each replayed over the whole load case (A, B 96 h, C 104 h, D 144 h).
One combination of a 96 h case takes about 10 s on an idle core and close to a minute on this
shared, loaded machine, which is why the subset is that small.
``--quick``: the first 24 h of each load case and 2 combinations (CP 8.5 h).

Figures per load case ``<case>`` = ``load-case-A`` .. ``load-case-D``:

- ``talc.<case>.p99_lin_um`` / ``talc.<case>.q_prod_pct``: the lowest P99_lin with
  Q_prod >= 95 % *within the subset* (NaN if none reaches 95 %), ``talc.<case>.best_params``;
- ``talc.<case>.subset_combinations``: how many combinations that best was chosen from;
- ``sweep.<case>.replayed_h``: hours of the load case replayed per combination (the full-grid
  times below are for that length: with ``--quick`` they are for the 24 h excerpt only);
- ``sweep.<case>.seconds_per_combination``: median replay time of one combination (one core);
- ``sweep.<case>.full_grid_s_one_core``: 2,191 x that;
- ``sweep.<case>.full_grid_s_parallel``: 2,191 x (subset wall time / subset size) with the
  ``jobs`` worker processes used here (``sweep.jobs``).
"""
from __future__ import annotations

import math
import os
import pathlib
import tempfile
import time
from typing import Any

from .sweep import (THESIS_COMBINATIONS_PER_LOAD_CASE, TALC_INPUTS, SweepRun, best_under_constraint,
                    plot_sweep, run_sweep, seconds_per_combination, select_points, table_6_1_grid, write_table)
from .replay_summary import PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM

LOAD_CASES = ("load-case-A", "load-case-B", "load-case-C", "load-case-D")
#: Table 6.3: (CP h, post-CP interval h, NG measurements, NG interval min) of cases A-D.
TABLE_6_3_SETS = ((8.5, 10.0, 12.0, 30.0), (8.5, 2.0, 6.0, 30.0), (12.0, 2.0, 18.0, 5.0), (8.5, 3.0, 12.0, 10.0))
QUICK_HOURS = 24.0
QUICK_COMBINATIONS = 2


def subset_points(quick: bool) -> list:
    grid = table_6_1_grid(24.0)
    pts = [p for p in grid
           if (p.cp_length_h, p.post_cp_interval_h, p.ng_measurements, p.ng_interval_min) in TABLE_6_3_SETS]
    if quick:
        pts = select_points([p for p in pts if p.cp_length_h == 8.5], None, QUICK_COMBINATIONS)
    return pts


def _recording(scenario: str, hours: float | None):
    from thermal_twin.scenarios import make_timeline
    from thermal_twin.simulate import simulate
    return simulate("nmv5000", make_timeline("nmv5000", scenario, hours=hours, seed=0), seed=0).to_recording()


def _r(v: float, nd: int = 2) -> float:
    return round(float(v), nd) if math.isfinite(v) else float(v)


def sweep_case(scenario: str, quick: bool, jobs: int, out_dir: pathlib.Path | None) -> tuple[dict[str, Any], str]:
    rec = _recording(scenario, QUICK_HOURS if quick else None)
    run = SweepRun("talc", {"input_names": list(TALC_INPUTS)}, PROBE_NOISE_LINEAR_UM, PROBE_NOISE_ANGULAR_UM_PER_M,
                   PROBE_RESOLUTION_UM, 0, f"twin nmv5000 {scenario} seed 0 hours {QUICK_HOURS if quick else 'all'}")
    points = subset_points(quick)
    with tempfile.TemporaryDirectory() as tmp:      # always measured afresh, never resumed
        t0 = time.perf_counter()
        res = run_sweep(rec, run, points, pathlib.Path(tmp) / "results.jsonl", jobs=jobs, progress=True)
        wall = time.perf_counter() - t0
    rows = res["rows"]
    best = best_under_constraint(rows)
    spc = seconds_per_combination(rows)
    key = f"talc.{scenario}"
    out: dict[str, Any] = {
        f"{key}.p99_lin_um": _r(best["p99_lin_um"]) if best else math.nan,
        f"{key}.q_prod_pct": _r(best["q_prod_pct"]) if best else math.nan,
        f"{key}.p99_ang_um_per_m": _r(best["p99_ang_um_per_m"]) if best else math.nan,
        f"{key}.best_params": (", ".join(f"{k}={v:g}" for k, v in best["params"].items()) if best
                               else "none with Q_prod >= 95 %"),
        f"{key}.subset_combinations": len(rows),
        f"sweep.{scenario}.replayed_h": _r(float(rec.time_s[-1] - rec.time_s[0]) / 3600.0, 1),
        f"sweep.{scenario}.seconds_per_combination": _r(spc),
        f"sweep.{scenario}.full_grid_s_one_core": _r(THESIS_COMBINATIONS_PER_LOAD_CASE * spc, 0),
        f"sweep.{scenario}.full_grid_s_parallel": _r(THESIS_COMBINATIONS_PER_LOAD_CASE * wall / len(rows), 0),
    }
    if out_dir is not None:
        case_dir = out_dir / f"sweep_{scenario}"
        case_dir.mkdir(parents=True, exist_ok=True)
        write_table(rows, case_dir / "table.csv")
        plot_sweep(rows, case_dir, title=f"{scenario} (subset)")
    line = (f"{scenario}: {len(rows)} combinations (subset), best with Q_prod >= 95 %: "
            + (f"P99_lin {best['p99_lin_um']:.2f} um at Q_prod {best['q_prod_pct']:.2f} %" if best else "none")
            + f"; {spc:.1f} s per combination -> full grid {THESIS_COMBINATIONS_PER_LOAD_CASE * wall / len(rows) / 3600:.1f} h"
            f" with {jobs} jobs")
    return out, line


def run(args) -> dict[str, Any]:
    """Figures of the TALC sweeps (``args.quick``: 24 h, 2 combinations per load case)."""
    quick = bool(getattr(args, "quick", False))
    out_dir = getattr(args, "out_dir", None)
    out_dir = pathlib.Path(out_dir) if out_dir else None
    jobs = max(1, os.cpu_count() or 1)
    out: dict[str, Any] = {"sweep.jobs": jobs, "sweep.quick": quick,
                           "sweep.full_grid_combinations_per_load_case": THESIS_COMBINATIONS_PER_LOAD_CASE,
                           "talc.subset": ("quick: first 24 h, 2 combinations (CP 8.5 h)" if quick else
                                           "the 4 Table 6.3 sets on every case, update 24 h "
                                           "(4 of 2,191 combinations)")}
    lines = []
    for case in LOAD_CASES:
        figs, line = sweep_case(case, quick, jobs, out_dir)
        out.update(figs)
        lines.append(line)
        print(line, flush=True)
    return out
