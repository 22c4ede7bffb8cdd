"""The sweep on a Dask LocalCluster gives the local pool's answers, resumes, and survives a killed worker."""
from __future__ import annotations

import json
import math
import os
import pathlib
import signal
import sys
import uuid

import pytest

from thermal_comp_common.runtime.task_engine import EngineSpec, TaskEngineError, map_tasks
from thermal_eval.sweep.grid import SweepPoint, SweepRun, best_under_constraint, read_results, run_sweep
from thermal_eval.sweep.cli import main as sweep_main


def _strip(rows):
    """A row without its wall time (the only field that may differ between two runs)."""
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]


def test_engine_spec_names_the_bad_field():
    with pytest.raises(TaskEngineError, match="engine: 'ray'"):
        EngineSpec("ray")
    with pytest.raises(TaskEngineError, match="address: 'tcp://x:1' is given but engine is 'local'"):
        EngineSpec("local", "tcp://x:1")
    with pytest.raises(TaskEngineError, match="address: 'localhost:8786'"):
        EngineSpec("dask", "localhost:8786")
    with pytest.raises(TaskEngineError, match="workers: 0"):
        EngineSpec("local", workers=0)
    with pytest.raises(TaskEngineError, match="retries: -1"):
        EngineSpec("dask", retries=-1)


def _square(shared, item):
    return shared * item * item


def test_map_tasks_streams_every_result_once_on_each_engine():
    items = list(range(7))
    for spec in (EngineSpec("local", workers=1), EngineSpec("local", workers=2)):
        got = dict(map_tasks(_square, 3, items, spec))
        assert got == {i: 3 * i * i for i in items}, spec


@pytest.mark.slow
def test_dask_local_cluster_sweep_equals_local_pool_and_resumes(short_csv, tmp_path):
    argv = [str(short_csv), "--limit", "3", "--grid-subset", "cp_length_h=8.5;post_cp_interval_h=1,3,inf",
            "--no-progress"]
    assert sweep_main(argv + ["--out", str(tmp_path / "local"), "--jobs", "2"]) == 0
    dask_argv = argv + ["--out", str(tmp_path / "dask"), "--jobs", "2", "--engine", "dask"]
    assert sweep_main(dask_argv) == 0
    local_rows, _ = read_results(tmp_path / "local" / "results.jsonl")
    dask_rows, _ = read_results(tmp_path / "dask" / "results.jsonl")
    assert len(dask_rows) == 3
    by_key = lambda rows: sorted(_strip(rows), key=lambda r: r["key"])          # noqa: E731
    assert by_key(dask_rows) == by_key(local_rows)                             # same seeds, same answers
    best_local = json.loads((tmp_path / "local" / "best.json").read_text())
    best_dask = json.loads((tmp_path / "dask" / "best.json").read_text())
    assert best_dask["engine"] == "dask LocalCluster of 2"
    assert (best_dask["best"] or {}).get("key") == (best_local["best"] or {}).get("key")
    # resumed on a running cluster given by its address: nothing recomputed, then one more point
    from distributed import LocalCluster
    before = (tmp_path / "dask" / "results.jsonl").read_text()
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        at = ["--engine", "dask", "--address", cluster.scheduler_address, "--out", str(tmp_path / "dask")]
        assert sweep_main(argv + at) == 0
        assert json.loads((tmp_path / "dask" / "best.json").read_text())["computed"] == 0
        assert (tmp_path / "dask" / "results.jsonl").read_text() == before
        more = [a if a != "3" else "5" for a in argv]                # --limit 5: the 3 done + 2 new points
        assert sweep_main(more + at) == 0
    summary = json.loads((tmp_path / "dask" / "best.json").read_text())
    assert summary["computed"] == 2 and summary["combinations"] == 5
    assert summary["engine"].startswith("dask at tcp://")
    assert (tmp_path / "dask" / "results.jsonl").read_text().startswith(before)


# ------------------------------------------------------------------ a worker killed mid-sweep
def _kill_once_evaluate(recording, run, point):
    """Stands in for the replay (the runner's bookkeeping is tested): logs each call in a file and,
    the first time it meets ``recording['kill_key']``, SIGKILLs its own worker process mid-task."""
    calls = pathlib.Path(recording["dir"])
    (calls / f"{point.key()}#{uuid.uuid4().hex}").touch()
    marker = calls.parent / "killed"
    if point.key() == recording["kill_key"] and not marker.exists():
        marker.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return {"key": point.key(), "run": run.fingerprint(), "params": point.config(),
            "p99_lin_um": point.cp_length_h + point.ng_measurements, "q_prod_pct": 99.0 - point.ng_interval_min / 10,
            "p99_ang_um_per_m": 1.0, "p99": {}, "rms": {}, "seconds": 0.0}


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["local", "dask"])
def test_a_killed_worker_is_retried_without_losing_finished_results(engine, tmp_path):
    import cloudpickle
    cloudpickle.register_pickle_by_value(sys.modules[__name__])    # dask workers cannot import a test module
    calls = tmp_path / "calls"
    calls.mkdir()
    points = [SweepPoint(8.5, 2.0, ngi, ngm, 24.0) for ngi in (5.0, 10.0, 20.0) for ngm in (6.0, 12.0)]
    kill_key = points[3].key()
    rec = {"dir": str(calls), "kill_key": kill_key}
    run = SweepRun("talc", {}, 0.25, 1.2, 0.25, 0, "kill test")
    path = tmp_path / "results.jsonl"
    res = run_sweep(rec, run, points, path, progress=False, evaluate=_kill_once_evaluate,
                    engine=EngineSpec(engine, workers=2, retries=2))
    assert (tmp_path / "killed").exists()                          # a worker did die mid-sweep
    assert res["computed"] == len(points)
    rows, warnings = read_results(path, run.fingerprint())
    assert not warnings and sorted(r["key"] for r in rows) == sorted(p.key() for p in points)
    expected = [_kill_once_evaluate({"dir": str(tmp_path), "kill_key": ""}, run, p) for p in points]
    assert sorted(_strip(rows), key=lambda r: r["key"]) == sorted(_strip(expected), key=lambda r: r["key"])
    n_calls = {p.key(): sum(1 for f in calls.iterdir() if f.name.split("#")[0] == p.key()) for p in points}
    assert n_calls[kill_key] == 2                                  # the killed task ran again
    assert all(1 <= n <= 2 for n in n_calls.values())              # nothing run more than once again
    best = best_under_constraint(rows)
    assert best is not None and math.isfinite(best["p99_lin_um"])
    res2 = run_sweep(rec, run, points, path, progress=False, evaluate=_kill_once_evaluate,
                     engine=EngineSpec(engine, workers=2))
    assert res2["computed"] == 0 and res2["skipped"] == len(points)


def test_local_pool_gives_up_after_its_retries(tmp_path):
    calls = tmp_path / "calls"
    calls.mkdir()
    points = [SweepPoint(8.5, 2.0, 5.0, ngm, 24.0) for ngm in (6.0, 12.0, 18.0)]
    rec = {"dir": str(calls), "kill_key": points[1].key()}
    run = SweepRun("talc", {}, 0.25, 1.2, 0.25, 0, "kill test")
    with pytest.raises(TaskEngineError, match="died 1 times.*retries=0"):
        run_sweep(rec, run, points, tmp_path / "r.jsonl", progress=False, evaluate=_kill_once_evaluate,
                  engine=EngineSpec("local", workers=2, retries=0))
    rows, _ = read_results(tmp_path / "r.jsonl", run.fingerprint())
    assert points[1].key() not in {r["key"] for r in rows}        # what finished is kept, the rest is not faked


def test_no_scheduler_at_the_address_is_one_clear_error():
    with pytest.raises(TaskEngineError, match=r"address: no dask scheduler answered at 'tcp://127\.0\.0\.1:9'"):
        list(map_tasks(_square, 1, [1, 2], EngineSpec("dask", "tcp://127.0.0.1:9", timeout_s=2.0)))


def test_projection_model_of_the_scale_bench():
    from thermal_eval.bench.scale import project_wall_s
    costs = {"A": 2.0, "B": 3.0}
    # N (2 + 3) (1 + 0.05) / W + 2 N o_s
    assert project_wall_s(costs, 0.05, 0.01, 4, per_case=100) == pytest.approx(100 * 5 * 1.05 / 4 + 200 * 0.01)
    assert project_wall_s(costs, 0.0, 0.0, 1, per_case=2191) == pytest.approx(2191 * 5.0)


def _fails_on_two(shared, item):
    if item == 2:
        raise ValueError(f"item {item}: bad on purpose")
    return item


@pytest.mark.slow
def test_a_raising_task_stops_the_dask_map_with_its_own_error():
    with pytest.raises(ValueError, match="item 2: bad on purpose"):
        list(map_tasks(_fails_on_two, None, range(4), EngineSpec("dask", workers=1)))
