"""``thermal-comp bench scale``: sweep throughput on 1 and 2 local workers and a Dask cluster of 2.

What it measures, on a small subset of the Table 6.1 grid (``--points``, default 8, spread evenly
over the 2,191 combinations) on the twin's load case A (``--quick``: its first 24 h, 4 points):

- replays per second with the local pool of 1 and 2 processes and a Dask ``LocalCluster`` of 2
  single-threaded worker processes (the cluster is started beforehand; its start-up is reported
  apart, ``scale.dask2.cluster_start_s``), and the parallel efficiency ``wall_1 / (W wall_W)``;
- ``c``: a replay's cost, the mean time a worker spends inside one replay (each row's
  ``seconds``); ``o``: the engine's overhead per replay, the worker time not spent replaying,
  ``(W wall - sum of replay times) / N``, also as % of ``c``;
- the same in CPU time, which other jobs on the same cores barely change (wall time doubles when
  they take half the cores): ``c_cpu``, the CPU time of the worker thread inside one replay, and
  ``o_cpu = (CPU of every process of the engine during the run - sum of c_cpu) / N`` (this
  process, with the dask scheduler and client, plus its worker processes, alive or reaped), and
  each engine's replay CPU beside the one-process run's (same combinations: 1.0 = no slower);
- ``o_s``: the serial cost per task of the dask scheduler and client (a round trip of 200 empty
  tasks; wall, and this process's CPU), the one part that does not shrink with more workers;
- the projected wall time of all four load cases' full grids (4 x 2,191 replays) on W dedicated
  cores, ``T(W) = sum_case N c_case (1 + o / c) / W + 4 N o_s``, from the CPU figures:
  ``c_case`` = ``c_cpu`` per load case (two combinations each, one worker; ``--quick``: load case
  A's for all four), ``o / c`` = ``o_cpu / c_cpu`` of the dask run, ``o_s`` the serial CPU per task.
  The load average before and after each run says how shared the cores were.

The results are identical on every engine (checked here too: the rows, without their timings).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import resource
import statistics
import tempfile
import time
from typing import Any

import psutil

from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks, start_local_cluster
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate
from thermal_eval.bench.sweep import LOAD_CASES, QUICK_HOURS
from thermal_eval.replay.summary import PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM
from thermal_eval.sweep.grid import (TALC_INPUTS, THESIS_COMBINATIONS_PER_LOAD_CASE, SweepRun, evaluate_point, run_sweep,
                                select_points, table_6_1_grid)

PROJECTED_WORKERS = (2, 16, 64)
NOOP_TASKS = 200
TIMING_FIELDS = ("seconds", "cpu_s", "pid")
IDLE_WINDOW_S = 3.0


def _recording(case: str, hours: float | None):
    return simulate("nmv5000", make_timeline("nmv5000", case, hours=hours, seed=0), seed=0).to_recording()


def _sweep_run(case: str, hours: float | None) -> SweepRun:
    return SweepRun("talc", {"input_names": list(TALC_INPUTS)}, PROBE_NOISE_LINEAR_UM, PROBE_NOISE_ANGULAR_UM_PER_M,
                    PROBE_RESOLUTION_UM, 0, f"twin nmv5000 {case} seed 0 hours {hours or 'all'}")


def cpu_evaluate(recording, run: SweepRun, point) -> dict[str, Any]:
    """:func:`evaluate_point` with the CPU time of the worker thread inside it (``cpu_s``) and the
    worker's ``pid``: the sweep's ``evaluate`` on every engine of this bench."""
    t0 = time.thread_time()
    row = evaluate_point(recording, run, point)
    return {**row, "cpu_s": time.thread_time() - t0, "pid": os.getpid()}


def _cpu_snapshot() -> tuple[float, dict[int, float], float]:
    """CPU seconds so far of this process, of each living descendant, and of the reaped ones."""
    alive = {}
    for proc in psutil.Process().children(recursive=True):
        try:
            t = proc.cpu_times()
        except psutil.Error:                 # ended between the listing and the read
            continue
        alive[proc.pid] = t.user + t.system
    reaped = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), alive, reaped.ru_utime + reaped.ru_stime


def cpu_since(before: tuple[float, dict[int, float], float]) -> float:
    """CPU seconds spent since ``before`` by this process and all its descendants (a worker started
    and reaped in between counts whole, through RUSAGE_CHILDREN)."""
    own0, alive0, reaped0 = before
    own1, alive1, reaped1 = _cpu_snapshot()
    return own1 - own0 + sum(t - alive0.get(pid, 0.0) for pid, t in alive1.items()) + reaped1 - reaped0


def _timed_sweep(rec, run: SweepRun, points, engine: EngineSpec) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:          # measured afresh, never resumed
        load0, cpu0, t0 = os.getloadavg()[0], _cpu_snapshot(), time.perf_counter()
        res = run_sweep(rec, run, points, pathlib.Path(tmp) / "results.jsonl", progress=False, engine=engine,
                        evaluate=cpu_evaluate)
        wall, cpu = time.perf_counter() - t0, cpu_since(cpu0)
    rows = res["rows"]
    busy, busy_cpu = sum(r["seconds"] for r in rows), sum(r["cpu_s"] for r in rows)
    n, w = len(rows), engine.workers
    c, c_cpu = busy / n, busy_cpu / n
    o, o_cpu = (w * wall - busy) / n, (cpu - busy_cpu) / n
    return {"rows": rows, "wall_s": wall, "replays_per_s": n / wall, "c_s": c, "o_s": o,
            "overhead_pct": 100.0 * o / c, "c_cpu_s": c_cpu, "o_cpu_s": o_cpu, "overhead_cpu_pct": 100.0 * o_cpu / c_cpu,
            "processes": len({r["pid"] for r in rows}), "load": [load0, os.getloadavg()[0]]}


def _noop(shared, item):
    return item


def _serial_task_cost(address: str) -> tuple[float, float]:
    """Wall time and this process's CPU time (client + scheduler) per task of ``NOOP_TASKS`` empty
    tasks on the cluster."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    n = sum(1 for _ in map_tasks(_noop, None, range(NOOP_TASKS), EngineSpec("dask", address, 2)))
    return (time.perf_counter() - t0) / n, (time.process_time() - cpu0) / n


def _strip(rows) -> list[str]:
    """Each row without its timings, as its JSON line (NaN as NaN: a not-yet-calibrated model's
    NaN figures compare equal, as they do in the results file)."""
    return sorted(json.dumps({k: v for k, v in r.items() if k not in TIMING_FIELDS}, sort_keys=True) for r in rows)


def _warm_point(points):
    """A grid combination outside ``points``: the warm-up replay (its imports, its first-call costs)."""
    chosen = {p.key() for p in points}
    return next(p for p in table_6_1_grid() if p.key() not in chosen)


def _warm_dask(address: str, rec, run_: SweepRun, point) -> tuple[float, float]:
    """One replay of ``point`` on every worker of the cluster (untimed by the sweep figures, as the
    cluster's start-up): the longest worker's replay CPU, and the cluster's idle CPU per second after."""
    from distributed import Client  # heavy: dask only for a cluster
    with Client(address, timeout=30) as client:
        first = client.run(cpu_evaluate, rec, run_, point)
        cpu0, t0 = _cpu_snapshot(), time.perf_counter()
        time.sleep(IDLE_WINDOW_S)            # the cluster at rest: heartbeats, monitors
        idle = cpu_since(cpu0) / (time.perf_counter() - t0)
    return max(r["cpu_s"] for r in first.values()), idle


def _case_costs(quick: bool, c_a: float) -> dict[str, float]:
    """Mean replay CPU cost of each load case (two combinations, one worker)."""
    if quick:
        return {case: c_a for case in LOAD_CASES}
    pts = select_points(table_6_1_grid(), None, 2)
    out = {}
    for case in LOAD_CASES:
        res = _timed_sweep(_recording(case, None), _sweep_run(case, None), pts, EngineSpec("local", workers=1))
        out[case] = res["c_cpu_s"]
    return out


def project_wall_s(case_costs: dict[str, float], overhead_fraction: float, serial_s: float, workers: int,
                   per_case: int = THESIS_COMBINATIONS_PER_LOAD_CASE) -> float:
    """``T(W) = sum_case N c_case (1 + o/c) / W + (cases x N) o_s`` (see the module docstring)."""
    return (sum(per_case * c for c in case_costs.values()) * (1.0 + overhead_fraction) / workers
            + len(case_costs) * per_case * serial_s)


def _engine_figures(name: str, res: dict[str, Any], base: dict[str, Any]) -> dict[str, Any]:
    """One engine's figures (wall and CPU) and its line on the console; ``base``: the local1 run."""
    w = 1 if name == "local1" else 2
    eff = base["wall_s"] / (w * res["wall_s"])
    cpu_ratio = res["c_cpu_s"] / base["c_cpu_s"]
    print(f"{name}: {res['replays_per_s']:.3f} replays/s, replay {res['c_s']:.2f} s, overhead "
          f"{res['o_s'] * 1000:.0f} ms per replay ({res['overhead_pct']:.1f} %), efficiency {eff:.2f}; "
          f"CPU: replay {res['c_cpu_s']:.2f} s ({cpu_ratio:.2f} x local1), engine "
          f"{res['o_cpu_s'] * 1000:.0f} ms per replay ({res['overhead_cpu_pct']:.1f} %); load "
          f"{res['load'][0]:.1f} -> {res['load'][1]:.1f}", flush=True)
    return {f"scale.{name}.replays_per_s": round(res["replays_per_s"], 3),
            f"scale.{name}.wall_s": round(res["wall_s"], 2),
            f"scale.{name}.replay_cost_s": round(res["c_s"], 3),
            f"scale.{name}.overhead_per_replay_s": round(res["o_s"], 4),
            f"scale.{name}.overhead_pct_of_replay": round(res["overhead_pct"], 2),
            f"scale.{name}.parallel_efficiency": round(eff, 3),
            f"scale.{name}.replay_cpu_s": round(res["c_cpu_s"], 3),
            f"scale.{name}.replay_cpu_vs_local1": round(cpu_ratio, 3),
            f"scale.{name}.engine_cpu_per_replay_s": round(res["o_cpu_s"], 4),
            f"scale.{name}.engine_cpu_pct_of_replay": round(res["overhead_cpu_pct"], 2),
            f"scale.{name}.worker_processes": res["processes"],
            f"scale.{name}.load_average_1min_before_after": [round(v, 1) for v in res["load"]]}


def _measure(rec, run_: SweepRun, points) -> tuple[dict[str, Any], dict[str, Any]]:
    """The three timed sweeps, every engine warm (see the module docstring), and the figures around
    them: cold and warm replay CPU of this process, cluster start, worker warm-up, idle CPU, ``o_s``."""
    warm = _warm_point(points)
    cold_cpu = cpu_evaluate(rec, run_, warm)["cpu_s"]          # this process's first replay: its imports
    warm_cpu = cpu_evaluate(rec, run_, warm)["cpu_s"]          # the local pool forks from here: warm too
    results = {"local1": _timed_sweep(rec, run_, points, EngineSpec("local", workers=1)),
               "local2": _timed_sweep(rec, run_, points, EngineSpec("local", workers=2))}
    t0 = time.perf_counter()
    cluster = start_local_cluster(2, EngineSpec().retries)      # the engine's own LocalCluster, as a sweep starts it
    try:
        start_s = time.perf_counter() - t0
        address = cluster.scheduler_address
        worker_first_cpu, idle = _warm_dask(address, rec, run_, warm)
        results["dask2"] = _timed_sweep(rec, run_, points, EngineSpec("dask", address, 2))
        serial, serial_cpu = _serial_task_cost(address)
    finally:
        cluster.close()
    d = results["dask2"]
    d["o_task_cpu_s"] = d["o_cpu_s"] - idle * d["wall_s"] / len(d["rows"])
    figures = {"scale.warm_replay_cpu_s": round(warm_cpu, 3),
               "scale.first_replay_extra_cpu_s.this_process": round(cold_cpu - warm_cpu, 3),
               "scale.first_replay_extra_cpu_s.dask_worker": round(worker_first_cpu - warm_cpu, 3),
               "scale.dask2.cluster_start_s": round(start_s, 2),
               "scale.dask2.idle_cpu_per_s": round(idle, 4),
               "scale.dask2.engine_cpu_per_replay_busy_s": round(d["o_task_cpu_s"], 4),
               "scale.dask2.engine_cpu_busy_pct_of_replay": round(100.0 * d["o_task_cpu_s"] / d["c_cpu_s"], 2),
               "scale.dask.serial_cost_per_task_ms": round(serial * 1000.0, 2),
               "scale.dask.serial_cpu_per_task_ms": round(serial_cpu * 1000.0, 2),
               "_serial_cpu": serial_cpu, "_idle": idle}
    return results, figures


def run(args) -> dict[str, Any]:
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
    results, figures = _measure(rec, run_, points)
    serial_cpu, idle = figures.pop("_serial_cpu"), figures.pop("_idle")
    out.update(figures)
    for name, res in results.items():
        out.update(_engine_figures(name, res, results["local1"]))
    out["scale.identical_results"] = (_strip(results["dask2"]["rows"]) == _strip(results["local1"]["rows"])
                                      == _strip(results["local2"]["rows"]))
    costs = _case_costs(quick, results["local1"]["c_cpu_s"])
    d = results["dask2"]
    # on dedicated cores: the per-task engine CPU, plus the idle CPU each worker's share adds per second
    o = max(0.0, d["o_task_cpu_s"] / d["c_cpu_s"] + idle / 2)
    out["scale.projection_overhead_fraction"] = round(o, 4)
    out.update({f"scale.replay_cpu_s.{case}": round(c, 3) for case, c in costs.items()})
    if not all(math.isfinite(v) for v in costs.values()):
        raise RuntimeError(f"a replay cost is not finite: {costs}")
    for w in PROJECTED_WORKERS:
        t = project_wall_s(costs, o, serial_cpu, w)
        out[f"scale.projected_all_four_full_grids_h.workers_{w}"] = round(t / 3600.0, 2)
        print(f"projected: all four load cases' full grids ({4 * THESIS_COMBINATIONS_PER_LOAD_CASE} replays) "
              f"on {w} dedicated cores: {t / 3600.0:.2f} h", flush=True)
    out["scale.model"] = ("T(W) = sum_case N c_case (1 + o/c) / W + 4 N o_s, N = 2191, on W dedicated cores; "
                          "c_case replay CPU, o/c = dask2 busy engine CPU / c + idle CPU per worker-second, "
                          "o_s serial CPU per task, all measured")
    # other jobs on the same cores inflate the wall figures (c, o, efficiency), hardly the CPU ones
    out["scale.load_average_1min_before_after"] = [round(load_before, 1), round(os.getloadavg()[0], 1)]
    out["scale.median_replay_s_local1"] = round(statistics.median(r["seconds"] for r in results["local1"]["rows"]), 3)
    return out
