"""``thermal-comp bench models``: TALC parameter sweeps on the twin's load cases A-D.

Inputs: the thesis's three temperatures plus the MWF state flag of the CNC
(``sweep.TALC_INPUTS``); in the dry load cases A-C the flag never varies and TALC leaves it
out, so only D differs from the thesis's input set. D is also swept with the thesis's three
inputs only (``talc.load-case-D.thesis_inputs.*``), to show what the flag is worth.

Combinations per load case (the same rule for every case, fixed before any result was seen):

- the four recommended sets of the thesis (Table 6.3, one per load case there);
- a coarse factorial over Table 6.1's values: CP 8.5 / 12 / 24 h x post-CP interval 1 / 2 / 3 /
  6 h x NG interval 5 / 10 / 20 / 30 min x NG measurements 6 / 12 / 24 (``COARSE_GRID``);
- update interval 24 h (Table 6.4) throughout.

That is 146 of the 2,191 combinations of Table 6.1 per load case (the sets of B and D are
factorial points themselves; ``--full`` runs all 2,191:
hours on this machine; ``thermal-comp sweep`` does the same with resume and plots).
``--quick``: the first 24 h of each load case and 2 combinations (CP 8.5 h).
``--engine dask --address tcp://HOST:8786``: the replays on a Dask cluster (docs/distributed.md);
``--engine dask`` alone: a LocalCluster of as many workers as cores.

Figures per load case ``<case>`` = ``load-case-A`` .. ``load-case-D``:

- ``talc.<case>.p99_lin_um`` / ``talc.<case>.q_prod_pct``: the lowest P99_lin with
  Q_prod >= 95 % *among the combinations run* (NaN if none reaches 95 %),
  ``talc.<case>.best_params``, ``talc.<case>.combinations``;
- ``talc.<case>.probe_and_hold_p99_lin_um`` / ``.p99_lin_over_probe_and_hold``: probe-and-hold
  at the best row's Q_prod over the same instants (goal ratio <= 0.5), and
  ``talc.<case>.whole_run.*`` the same over the whole run (the CP included);
- ``talc.<case>.table_6_3.p99_lin_um`` / ``.q_prod_pct``: the thesis's recommended set for that case;
- ``sweep.<case>.replayed_h``: hours of the load case replayed per combination;
- ``sweep.<case>.seconds_per_combination``: median replay time of one combination (one core);
- ``sweep.<case>.wall_s``: wall time of the combinations run, with ``sweep.jobs`` workers;
- ``sweep.<case>.full_grid_s_parallel``: 2,191 x (wall time / combinations run), i.e. one full
  sweep of the load case with ``sweep.jobs`` workers (measured, not extrapolated, with ``--full``).
"""
from __future__ import annotations

import argparse

import math
import pathlib
import tempfile
import time
from typing import Any

from thermal_comp_common.runtime.task_engine import EngineSpec, default_workers
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate
from thermal_eval.sweep.grid import (THESIS_COMBINATIONS_PER_LOAD_CASE, THESIS_TALC_INPUTS, TALC_INPUTS, SweepPoint, SweepRun,
                    best_under_constraint, plot_sweep, run_sweep, seconds_per_combination, select_points,
                    table_6_1_grid, write_table)
from thermal_eval.replay.summary import PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM

LOAD_CASES = ("load-case-A", "load-case-B", "load-case-C", "load-case-D")
#: Table 6.3: (CP h, post-CP interval h, NG measurements, NG interval min) of cases A-D.
TABLE_6_3_SETS = ((8.5, 10.0, 12.0, 30.0), (8.5, 2.0, 6.0, 30.0), (12.0, 2.0, 18.0, 5.0), (8.5, 3.0, 12.0, 10.0))
QUICK_HOURS = 24.0
QUICK_COMBINATIONS = 2


#: The coarse factorial run on every load case besides the Table 6.3 sets (see the docstring).
COARSE_GRID = {"cp_length_h": (8.5, 12.0, 24.0), "post_cp_interval_h": (1.0, 2.0, 3.0, 6.0),
               "ng_interval_min": (5.0, 10.0, 20.0, 30.0), "ng_measurements": (6.0, 12.0, 24.0)}


def table_6_3_points(update_interval_h: float = 24.0) -> list[SweepPoint]:
    return [SweepPoint(cp, post, ngi, ngm, update_interval_h) for cp, post, ngm, ngi in TABLE_6_3_SETS]


def subset_points(quick: bool, full: bool = False) -> list[SweepPoint]:
    grid = table_6_1_grid(24.0)
    if full:
        return grid
    t63 = table_6_3_points()
    if quick:
        return select_points([p for p in t63 if p.cp_length_h == 8.5], None, QUICK_COMBINATIONS)
    coarse = select_points(grid, COARSE_GRID)
    return t63 + [p for p in coarse if p not in t63]


def _recording(scenario: str, hours: float | None):
    return simulate("nmv5000", make_timeline("nmv5000", scenario, hours=hours, seed=0), seed=0).to_recording()


def _r(v: float, nd: int = 2) -> float:
    return round(float(v), nd) if math.isfinite(v) else float(v)


def _pah(best, name: str) -> float:
    """A probe-and-hold figure of the best row (NaN without a best row)."""
    return _r(float((best or {}).get("probe_and_hold", {}).get(name, math.nan)))


def sweep_case(scenario: str, quick: bool, jobs: int, out_dir: pathlib.Path | None, full: bool = False,
               inputs: tuple[str, ...] = TALC_INPUTS, label: str = "",
               engine: EngineSpec | None = None) -> tuple[dict[str, Any], str]:
    """Sweep one load case; ``label`` (e.g. ``thesis_inputs``) names a variant's keys; ``engine``
    (default: a local pool of ``jobs``) where the replays run."""
    rec = _recording(scenario, QUICK_HOURS if quick else None)
    run = SweepRun("talc", {"input_names": list(inputs)}, PROBE_NOISE_LINEAR_UM, PROBE_NOISE_ANGULAR_UM_PER_M,
                   PROBE_RESOLUTION_UM, 0, f"twin nmv5000 {scenario} seed 0 hours {QUICK_HOURS if quick else 'all'}")
    points = subset_points(quick, full)
    with tempfile.TemporaryDirectory() as tmp:      # always measured afresh, never resumed
        t0 = time.perf_counter()
        res = run_sweep(rec, run, points, pathlib.Path(tmp) / "results.jsonl", jobs=jobs, progress=True,
                        engine=engine)
        wall = time.perf_counter() - t0
    rows = res["rows"]
    best = best_under_constraint(rows)
    spc = seconds_per_combination(rows)
    key = f"talc.{scenario}" + (f".{label}" if label else "")
    out: dict[str, Any] = {
        f"{key}.p99_lin_um": _r(best["p99_lin_um"]) if best else math.nan,
        f"{key}.q_prod_pct": _r(best["q_prod_pct"]) if best else math.nan,
        f"{key}.p99_ang_um_per_m": _r(best["p99_ang_um_per_m"]) if best else math.nan,
        f"{key}.best_params": (", ".join(f"{k}={v:g}" for k, v in best["params"].items()) if best
                               else "none with Q_prod >= 95 %"),
        f"{key}.best_p99_um": ({c: _r(v) for c, v in best["p99"].items()} if best else {}),
        f"{key}.probe_and_hold_p99_lin_um": _pah(best, "p99_lin_um"),
        f"{key}.probe_and_hold_p99_ang_um_per_m": _pah(best, "p99_ang_um_per_m"),
        f"{key}.p99_lin_over_probe_and_hold": _pah(best, "p99_lin_ratio"),
        f"{key}.whole_run.p99_lin_um": _pah(best, "whole_run_model_p99_lin_um"),
        f"{key}.whole_run.probe_and_hold_p99_lin_um": _pah(best, "whole_run_p99_lin_um"),
        f"{key}.whole_run.p99_lin_over_probe_and_hold": _pah(best, "whole_run_p99_lin_ratio"),
        f"{key}.inputs": ", ".join(inputs),
        f"{key}.combinations": len(rows),
    }
    if not label:
        out.update({
            f"sweep.{scenario}.replayed_h": _r(float(rec.time_s[-1] - rec.time_s[0]) / 3600.0, 1),
            f"sweep.{scenario}.seconds_per_combination": _r(spc),
            f"sweep.{scenario}.wall_s": _r(wall, 1),
            f"sweep.{scenario}.full_grid_s_parallel": _r(THESIS_COMBINATIONS_PER_LOAD_CASE * wall / len(rows), 0),
        })
    if out_dir is not None:
        case_dir = out_dir / (f"sweep_{scenario}" + (f"_{label}" if label else ""))
        case_dir.mkdir(parents=True, exist_ok=True)
        write_table(rows, case_dir / "table.csv")
        plot_sweep(rows, case_dir, title=f"{scenario} {label}".strip())
    line = (f"{scenario}{' ' + label if label else ''}: {len(rows)} combinations, best with Q_prod >= 95 %: "
            + (f"P99_lin {best['p99_lin_um']:.2f} um at Q_prod {best['q_prod_pct']:.2f} % "
               f"(probe-and-hold at that Q_prod {_pah(best, 'p99_lin_um'):.2f} um, "
               f"ratio {_pah(best, 'p99_lin_ratio'):.2f})" if best else "none")
            + f"; {spc:.1f} s per combination, {wall:.0f} s wall with {jobs} jobs"
            + ("" if label else f" -> one full sweep {THESIS_COMBINATIONS_PER_LOAD_CASE * wall / len(rows) / 60:.0f} min"))
    return out, line


def run(args) -> dict[str, Any]:
    """Figures of the TALC sweeps (``--quick``: 24 h, 2 combinations per load case;
    ``--full``: all 2,191 combinations of every load case)."""
    extra = argparse.ArgumentParser(prog="thermal-comp bench models")
    extra.add_argument("--full", action="store_true", help="the whole Table 6.1 grid (hours)")
    extra.add_argument("--cases", default=",".join(LOAD_CASES), help="comma-separated load cases")
    extra.add_argument("--engine", choices=("local", "dask"), default="local", help="where the replays run")
    extra.add_argument("--address", default=None, help="dask scheduler, e.g. tcp://host:8786 (docs/distributed.md)")
    opts, _ = extra.parse_known_args(list(getattr(args, "extra", []) or []))
    quick = bool(getattr(args, "quick", False))
    full = bool(opts.full) and not quick
    cases = [c.strip() for c in opts.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in LOAD_CASES]
    if unknown:
        raise ValueError(f"--cases: {unknown} are not load cases ({', '.join(LOAD_CASES)})")
    out_dir = getattr(args, "out_dir", None)
    out_dir = pathlib.Path(out_dir) if out_dir else None
    jobs = default_workers()
    engine = EngineSpec(opts.engine, opts.address, jobs)
    n = len(subset_points(quick, full))
    out: dict[str, Any] = {"sweep.jobs": jobs, "sweep.engine": engine.describe(), "sweep.quick": quick, "sweep.full": full,
                           "sweep.full_grid_combinations_per_load_case": THESIS_COMBINATIONS_PER_LOAD_CASE,
                           "talc.subset": ("quick: first 24 h, 2 combinations (CP 8.5 h)" if quick else
                                           "the whole Table 6.1 grid" if full else
                                           f"the 4 Table 6.3 sets + a coarse factorial of Table 6.1 values "
                                           f"({n} of 2,191 combinations), update 24 h")}
    for case in cases:
        figs, line = sweep_case(case, quick, jobs, out_dir, full, engine=engine)
        out.update(figs)
        print(line, flush=True)
        if case == "load-case-D":      # what the MWF flag is worth: the thesis's inputs only
            figs, line = sweep_case(case, quick, jobs, out_dir, full, THESIS_TALC_INPUTS, "thesis_inputs", engine)
            out.update(figs)
            print(line, flush=True)
    return out
