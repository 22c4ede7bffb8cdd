"""``thermal-comp bench scale``: sweep throughput on 1 and 2 local workers and a Dask cluster of 2.

What it measures, on a small subset of the Table 6.1 grid (``--points``, default 8, spread evenly
over the 2,191 combinations) on the twin's load case A (``--quick``: its first 24 h, 4 points):

- replays per second with the local pool of 1 and 2 processes and a Dask ``LocalCluster`` of 2
  single-threaded worker processes (the cluster is started beforehand; its start-up is reported
  apart, ``scale.dask2.cluster_start_s``), and the parallel efficiency ``wall_1 / (W wall_W)``;
- ``c``: a replay's cost, the mean time a worker spends inside one replay (each row's
  ``seconds``); ``o``: the engine's overhead per replay, the worker time not spent replaying,
  ``(W wall - sum of replay times) / N``, also as % of ``c``;
- ``o_s``: the serial cost per task of the dask scheduler and client (a round trip of 200 empty
  tasks), the one part that does not shrink with more workers;
- the projected wall time of all four load cases' full grids (4 x 2,191 replays) on W workers,
  ``T(W) = sum_case N c_case (1 + o / c) / W + 4 N o_s``, the overhead taken as the
  fraction ``o / c`` measured on the dask run (both grow alike when the cores are shared), with ``c_case`` measured per load case
  (two combinations each, one worker; ``--quick``: load case A's ``c`` for all four).

The results are identical on every engine (checked here too: the rows, without their timings).
"""
from __future__ import annotations

import argparse
import math
import os
import pathlib
import statistics
import tempfile
import time
from typing import Any

from thermal_comp_common.task_engine import EngineSpec, map_tasks
from thermal_eval.bench_sweep import LOAD_CASES, QUICK_HOURS
from thermal_eval.replay_summary import PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM
from thermal_eval.sweep import (TALC_INPUTS, THESIS_COMBINATIONS_PER_LOAD_CASE, SweepRun, run_sweep, select_points,
                                table_6_1_grid)

PROJECTED_WORKERS = (2, 16, 64)
NOOP_TASKS = 200


def _recording(case: str, hours: float | None):
    from thermal_twin.scenarios import make_timeline
    from thermal_twin.simulate import simulate
    return simulate("nmv5000", make_timeline("nmv5000", case, hours=hours, seed=0), seed=0).to_recording()


def _sweep_run(case: str, hours: float | None) -> SweepRun:
    return SweepRun("talc", {"input_names": list(TALC_INPUTS)}, PROBE_NOISE_LINEAR_UM, PROBE_NOISE_ANGULAR_UM_PER_M,
                    PROBE_RESOLUTION_UM, 0, f"twin nmv5000 {case} seed 0 hours {hours or 'all'}")


def _timed_sweep(rec, run: SweepRun, points, engine: EngineSpec) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:          # measured afresh, never resumed
        t0 = time.perf_counter()
        res = run_sweep(rec, run, points, pathlib.Path(tmp) / "results.jsonl", progress=False, engine=engine)
        wall = time.perf_counter() - t0
    rows = res["rows"]
    busy = sum(r["seconds"] for r in rows)
    n, w = len(rows), engine.workers
    c = busy / n
    o = (w * wall - busy) / n
    return {"rows": rows, "wall_s": wall, "replays_per_s": n / wall, "c_s": c, "o_s": o,
            "overhead_pct": 100.0 * o / c}


def _noop(shared, item):
    return item


def _serial_task_cost(address: str) -> float:
    """Wall time per task of ``NOOP_TASKS`` empty tasks on the cluster: scheduler + client cost."""
    t0 = time.perf_counter()
    n = sum(1 for _ in map_tasks(_noop, None, range(NOOP_TASKS), EngineSpec("dask", address, 2)))
    return (time.perf_counter() - t0) / n


def _strip(rows):
    return sorted(({k: v for k, v in r.items() if k != "seconds"} for r in rows), key=lambda r: r["key"])


def _case_costs(quick: bool, c_a: float) -> dict[str, float]:
    """Mean replay cost of each load case (two combinations, one worker)."""
    if quick:
        return {case: c_a for case in LOAD_CASES}
    pts = select_points(table_6_1_grid(), None, 2)
    out = {}
    for case in LOAD_CASES:
        res = _timed_sweep(_recording(case, None), _sweep_run(case, None), pts, EngineSpec("local", workers=1))
        out[case] = res["c_s"]
    return out


def project_wall_s(case_costs: dict[str, float], overhead_fraction: float, serial_s: float, workers: int,
                   per_case: int = THESIS_COMBINATIONS_PER_LOAD_CASE) -> float:
    """``T(W) = sum_case N c_case (1 + o/c) / W + (cases x N) o_s`` (see the module docstring)."""
    return (sum(per_case * c for c in case_costs.values()) * (1.0 + overhead_fraction) / workers
            + len(case_costs) * per_case * serial_s)


def run(args) -> dict[str, Any]:
    from distributed import LocalCluster
    extra = argparse.ArgumentParser(prog="thermal-comp bench scale")
    extra.add_argument("--points", type=int, default=None, help="combinations per engine (default 8, quick 4)")
    opts, _ = extra.parse_known_args(list(getattr(args, "extra", []) or []))
    quick = bool(getattr(args, "quick", False))
    n_points = opts.points or (4 if quick else 8)
    hours = QUICK_HOURS if quick else None
    load_before = os.getloadavg()[0]
    rec, run_ = _recording("load-case-A", hours), _sweep_run("load-case-A", hours)
    points = select_points(table_6_1_grid(), None, n_points)
    out: dict[str, Any] = {"scale.case": "load-case-A", "scale.replayed_h": round(
        float(rec.time_s[-1] - rec.time_s[0]) / 3600.0, 1), "scale.points": len(points)}
    results = {"local1": _timed_sweep(rec, run_, points, EngineSpec("local", workers=1)),
               "local2": _timed_sweep(rec, run_, points, EngineSpec("local", workers=2))}
    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        out["scale.dask2.cluster_start_s"] = round(time.perf_counter() - t0, 2)
        address = cluster.scheduler_address
        results["dask2"] = _timed_sweep(rec, run_, points, EngineSpec("dask", address, 2))
        serial = _serial_task_cost(address)
    finally:
        cluster.close()
    base = results["local1"]["wall_s"]
    for name, res in results.items():
        w = 1 if name == "local1" else 2
        out.update({f"scale.{name}.replays_per_s": round(res["replays_per_s"], 3),
                    f"scale.{name}.wall_s": round(res["wall_s"], 2),
                    f"scale.{name}.replay_cost_s": round(res["c_s"], 3),
                    f"scale.{name}.overhead_per_replay_s": round(res["o_s"], 4),
                    f"scale.{name}.overhead_pct_of_replay": round(res["overhead_pct"], 2),
                    f"scale.{name}.parallel_efficiency": round(base / (w * res["wall_s"]), 3)})
        print(f"{name}: {res['replays_per_s']:.3f} replays/s, replay {res['c_s']:.2f} s, overhead "
              f"{res['o_s'] * 1000:.0f} ms per replay ({res['overhead_pct']:.1f} %), efficiency "
              f"{base / (w * res['wall_s']):.2f}", flush=True)
    out["scale.identical_results"] = (_strip(results["dask2"]["rows"]) == _strip(results["local1"]["rows"])
                                      == _strip(results["local2"]["rows"]))
    out["scale.dask.serial_cost_per_task_ms"] = round(serial * 1000.0, 2)
    costs = _case_costs(quick, results["local1"]["c_s"])
    o = max(0.0, results["dask2"]["overhead_pct"] / 100.0)
    out.update({f"scale.replay_cost_s.{case}": round(c, 3) for case, c in costs.items()})
    for w in PROJECTED_WORKERS:
        t = project_wall_s(costs, o, serial, w)
        out[f"scale.projected_all_four_full_grids_h.workers_{w}"] = round(t / 3600.0, 2)
        print(f"projected: all four load cases' full grids ({4 * THESIS_COMBINATIONS_PER_LOAD_CASE} replays) "
              f"on {w} workers: {t / 3600.0:.2f} h", flush=True)
    if not all(math.isfinite(v) for v in costs.values()):
        raise RuntimeError(f"a replay cost is not finite: {costs}")
    out["scale.model"] = "T(W) = sum_case N c_case (1 + o/c) / W + 4 N o_s, N = 2191; c_case, o/c (dask2), o_s measured"
    # other jobs on the same cores inflate c and lower the efficiency: the load says how busy they were
    out["scale.load_average_1min_before_after"] = [round(load_before, 1), round(os.getloadavg()[0], 1)]
    out["scale.median_replay_s_local1"] = round(statistics.median(r["seconds"] for r in results["local1"]["rows"]), 3)
    return out
