"""The engine's own Dask LocalCluster runs numpy tasks as the local pool does: no page fault per
large array (dask's default MALLOC_TRIM_THRESHOLD_ makes one per page) and no sampling profiler."""
from __future__ import annotations

import os
import resource

import pytest

from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks, start_local_cluster

ARRAY_BYTES = 1 << 20          # above glibc's initial 128 KiB mmap threshold
PAGE_BYTES = os.sysconf("SC_PAGE_SIZE")


def _faults_of_array_churn(rounds, item):
    """Minor page faults of this thread while allocating, writing and freeing a 1 MiB array ``rounds`` times."""
    import dask
    import numpy as np
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    for _ in range(rounds):
        a = np.ones(ARRAY_BYTES // 8)
        del a
    faults = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before
    return faults, os.environ.get("MALLOC_TRIM_THRESHOLD_"), dask.config.get("distributed.worker.profile.enabled")


def _churn_on(cluster, rounds):
    spec = EngineSpec("dask", cluster.scheduler_address, 1)
    [(_, result)] = list(map_tasks(_faults_of_array_churn, rounds, [0], spec))
    return result


@pytest.mark.slow
def test_engine_cluster_reuses_freed_arrays_where_dask_default_faults_every_page(monkeypatch):
    from distributed import LocalCluster
    # the nanny exports its pre-spawn environment into this process: undo it after the test
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    rounds = 200
    every_page = rounds * ARRAY_BYTES // PAGE_BYTES
    cluster = start_local_cluster(1, 0)
    try:
        faults, trim, profiling = _churn_on(cluster, rounds)
    finally:
        cluster.close()
    assert trim is None and profiling is False
    assert faults < 0.1 * every_page, (faults, every_page)     # the freed array is reused, not refaulted
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    default = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        faults_default, trim_default, _ = _churn_on(default, rounds)
    finally:
        default.close()
    assert trim_default == "65536"                         # dask's default, the cause this engine avoids
    assert faults_default > 0.9 * every_page, (faults_default, every_page)
