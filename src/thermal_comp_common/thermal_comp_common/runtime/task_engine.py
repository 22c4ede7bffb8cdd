"""Map one function over many independent tasks, locally or on a Dask cluster, results streamed back.

The heavy offline work of thermal-comp (the Table 6.1 sweep, model comparisons over many
recordings, the candidate fits of a diagnosis) is the same shape: many pure tasks that share one
large read-only input (a recording). :func:`map_tasks` runs ``fn(shared, item)`` for every item
and yields ``(index, result)`` as each finishes, so a caller can write every result down at once
(resumable runs) and never holds the whole set in flight.

Two engines, one contract:

- ``local`` (default): a process pool on this computer (one process when ``workers == 1``);
- ``dask``: a Dask ``distributed`` cluster, given by its scheduler address (``tcp://host:8786``)
  or, without an address, a ``LocalCluster`` of ``workers`` single-threaded processes set for
  numpy tasks (:func:`start_local_cluster`).

A worker that dies (killed, out of memory) costs only the tasks it was running: the dask
scheduler reschedules them on the other workers, the local pool is rebuilt for the unfinished
tasks (at most ``retries`` times). Results already yielded are never recomputed by the engine.
Why Dask rather than Ray, and how to start a cluster: docs/distributed.md.
"""
from __future__ import annotations

import concurrent.futures
import os
import uuid
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

from thermal_comp_common.runtime.blas_threads import single_thread_blas

ENGINES = ("local", "dask")


class TaskEngineError(RuntimeError):
    """A bad engine setting (names the field and value) or a task that failed beyond its retries."""


@dataclass(frozen=True)
class EngineSpec:
    """Where tasks run. ``workers``: local pool size, or the LocalCluster's size for dask without
    ``address`` (ignored with an address: the cluster has the workers it has). ``retries``: how
    often the local pool is rebuilt, or a task rescheduled by a LocalCluster, after a worker died
    (a cluster given by address uses its scheduler's ``allowed-failures``). ``timeout_s``: how
    long to wait for a dask scheduler to answer."""

    kind: str = "local"
    address: str | None = None
    workers: int = 1
    retries: int = 2
    timeout_s: float = 30.0

    def __post_init__(self) -> None:
        if self.kind not in ENGINES:
            raise TaskEngineError(f"engine: {self.kind!r} is not one of {list(ENGINES)}")
        if self.address is not None and self.kind != "dask":
            raise TaskEngineError(f"address: {self.address!r} is given but engine is {self.kind!r} "
                                  f"(an address needs engine 'dask')")
        if self.address is not None and "://" not in self.address:
            raise TaskEngineError(f"address: {self.address!r} is not a scheduler address like tcp://host:8786")
        if not isinstance(self.workers, int) or self.workers < 1:
            raise TaskEngineError(f"workers: {self.workers!r} must be an integer >= 1")
        if not isinstance(self.retries, int) or self.retries < 0:
            raise TaskEngineError(f"retries: {self.retries!r} must be an integer >= 0")
        if not self.timeout_s > 0:
            raise TaskEngineError(f"timeout_s: {self.timeout_s!r} must be > 0")

    def describe(self) -> str:
        if self.kind == "local":
            return f"local pool of {self.workers}"
        return f"dask at {self.address}" if self.address else f"dask LocalCluster of {self.workers}"


def map_tasks(fn: Callable[[Any, Any], Any], shared: Any, items: Iterable[Any],
              spec: EngineSpec | None = None) -> Iterator[tuple[int, Any]]:
    """Yield ``(i, fn(shared, items[i]))`` for every item, in the order they finish.

    ``fn`` must be a module-level function importable on the workers (same installed packages);
    ``shared`` is sent once per worker, not once per task. A task that raises stops the map with
    that exception (deterministic tasks raise again on a retry, so they are not retried).
    """
    spec = spec or EngineSpec()
    items = list(items)
    if not items:
        return iter(())
    if spec.kind == "dask":
        return _dask_map(fn, shared, items, spec)
    if spec.workers == 1 or len(items) == 1:
        return ((i, _call(fn, shared, item)) for i, item in enumerate(items))
    return _local_pool_map(fn, shared, items, spec)


# ------------------------------------------------------------------ worker side
_BLAS_LIMITED = False
_LOCAL: dict[str, Any] = {}


def _limit_blas() -> None:
    """One BLAS thread per worker process: the workers are the parallelism."""
    global _BLAS_LIMITED
    if _BLAS_LIMITED:
        return
    _BLAS_LIMITED = True
    single_thread_blas(openmp=True)          # not a context: holds for the worker's life


def _call(fn, shared, item):
    _limit_blas()
    return fn(shared, item)


def _init_local(fn, shared) -> None:
    _LOCAL["fn"], _LOCAL["shared"] = fn, shared


def _call_local(item):
    return _call(_LOCAL["fn"], _LOCAL["shared"], item)


# ------------------------------------------------------------------ local process pool
def _local_pool_map(fn, shared, items: list, spec: EngineSpec) -> Iterator[tuple[int, Any]]:
    pending = dict(enumerate(items))
    restarts = 0
    while pending:
        pool = concurrent.futures.ProcessPoolExecutor(max_workers=min(spec.workers, len(pending)),
                                                      initializer=_init_local, initargs=(fn, shared))
        futures = {pool.submit(_call_local, item): i for i, item in pending.items()}
        broken = False
        try:
            for fut in concurrent.futures.as_completed(futures):
                try:
                    result = fut.result()
                except BrokenProcessPool:
                    broken = True
                    break
                i = futures[fut]
                del pending[i]
                yield i, result
            if broken:        # results that finished before the pool broke are kept, not recomputed
                for fut, i in futures.items():
                    if i in pending and fut.done() and not fut.cancelled() and fut.exception() is None:
                        del pending[i]
                        yield i, fut.result()
        finally:
            pool.shutdown(wait=not broken, cancel_futures=True)
        if broken:
            restarts += 1
            if restarts > spec.retries:
                raise TaskEngineError(f"a worker of the local pool died {restarts} times; "
                                      f"{len(pending)} tasks unfinished (retries={spec.retries})")


# ------------------------------------------------------------------ dask
def _dask_map(fn, shared, items: list, spec: EngineSpec) -> Iterator[tuple[int, Any]]:
    try:
        from distributed import Client, as_completed  # heavy: dask only for engine dask
    except ImportError as exc:
        raise TaskEngineError("engine 'dask' needs the 'distributed' package (requirements/python.txt)") from exc
    cluster = None if spec.address is not None else start_local_cluster(spec.workers, spec.retries)
    try:
        try:
            client = Client(spec.address or cluster, timeout=spec.timeout_s)
        except OSError as exc:
            raise TaskEngineError(f"address: no dask scheduler answered at {spec.address!r} within "
                                  f"{spec.timeout_s:g} s ({exc})") from exc
        try:
            yield from _dask_run(client, as_completed, fn, shared, items, spec)
        finally:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()


# Dask's defaults for the worker processes a LocalCluster spawns, changed for replay-like tasks:
# - MALLOC_TRIM_THRESHOLD_=65536 (set by the nanny before spawning, so that freed memory goes back
#   to the OS) also switches off glibc's dynamic mmap threshold: every numpy array above 128 KiB is
#   then mmap'ed and page-faulted afresh, which costs a replay far more CPU time than in the local
#   pool; unset, the two are equal.
# - the statistical profiler samples every worker thread each 10 ms for the dashboard, which this
#   cluster does not serve;
# - the event-loop health tick (20 ms) and the system monitor (0.5 s, dashboard figures) wake every
#   process of the cluster; at 1 s and 5 s an idle cluster costs about a third of the CPU.
#   (figures: docs/distributed.md, "Scale figures")
LOCAL_CLUSTER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                        "distributed.worker.profile.enabled": False,
                        "distributed.admin.tick.interval": "1s",
                        "distributed.admin.system-monitor.interval": "5s"}


def start_local_cluster(workers: int, retries: int):
    """A Dask ``LocalCluster`` of ``workers`` single-threaded worker processes, no dashboard, set for
    CPU-bound numpy tasks (:data:`LOCAL_CLUSTER_CONFIG`); a task on workers that died more than
    ``retries`` times is given up (KilledWorker). The caller closes it."""
    try:
        # heavy: dask only for engine dask
        import dask
        from distributed import LocalCluster
    except ImportError as exc:
        raise TaskEngineError("engine 'dask' needs the 'distributed' package (requirements/python.txt)") from exc
    # a cluster given by address applies its own scheduler's allowed-failures (dask default 3)
    with dask.config.set({**LOCAL_CLUSTER_CONFIG, "distributed.scheduler.allowed-failures": retries}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)


def _dask_run(client, as_completed, fn, shared, items, spec) -> Iterator[tuple[int, Any]]:
    # broadcast: every worker holds the shared input, so one dying worker loses no copy of it
    shared_future = client.scatter(shared, broadcast=True, hash=False)
    run_id = uuid.uuid4().hex[:8]
    # no ``retries=`` here: dask's retries rerun tasks that *raised*, which a deterministic task
    # would do again; tasks of a dead worker are rescheduled by the scheduler itself
    futures = [client.submit(_call, fn, shared_future, item, key=f"task-{run_id}-{i}", pure=False)
               for i, item in enumerate(items)]
    index = {f.key: i for i, f in enumerate(futures)}
    try:
        for fut in as_completed(futures):
            result = fut.result()
            yield index[fut.key], result
            fut.release()
    finally:
        client.cancel(futures)


def default_workers() -> int:
    """The local pool's default size: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                   # not Linux
        return max(1, os.cpu_count() or 1)
