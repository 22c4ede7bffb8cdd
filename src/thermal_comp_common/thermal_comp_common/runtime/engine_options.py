"""The task engine's command-line options, said once, and one engine held for a whole run.

``thermal-comp diagnose`` and ``calibrate`` (and any later command whose work is many
independent tasks) take ``--engine local|dask --address tcp://HOST:PORT --jobs N
--retries N`` with the meaning ``thermal-comp sweep`` gives them (``--workers`` is accepted
for ``--jobs``). :func:`held_engine` serves a run that maps tasks several times (a diagnosis:
channel analysis, screening and fitting of every round, the out-of-vocabulary step):
``--engine dask`` without an address starts ONE LocalCluster for the whole run, instead of
one per map, and tears it down at the end. See docs/distributed.md.
"""
from __future__ import annotations

import argparse
import contextlib
from typing import Iterator

from thermal_comp_common.runtime.task_engine import ENGINES, EngineSpec, TaskEngineError, start_local_cluster


def add_engine_arguments(ap: argparse.ArgumentParser, default_jobs: int = 1, what: str = "tasks") -> None:
    """Add ``--engine --address --jobs/--workers --retries`` to ``ap``; ``what`` names the tasks."""
    g = ap.add_argument_group("task engine (docs/distributed.md)")
    g.add_argument("--engine", choices=ENGINES, default="local",
                   help=f"where the {what} run (default: local; one process with --jobs 1)")
    g.add_argument("--address", default=None, metavar="tcp://HOST:PORT",
                   help="the dask scheduler of a running cluster (with --engine dask)")
    g.add_argument("--jobs", "--workers", dest="jobs", type=int, default=default_jobs,
                   help=f"processes of the local pool, or the size of the dask LocalCluster started when "
                        f"--engine dask has no --address (default {default_jobs})")
    g.add_argument("--retries", type=int, default=2,
                   help="resubmissions of a task whose worker died (default %(default)s)")


def engine_from_args(args: argparse.Namespace) -> EngineSpec:
    """The :class:`EngineSpec` of parsed options (raises TaskEngineError naming a bad field)."""
    if args.jobs < 1:
        raise TaskEngineError(f"--jobs: {args.jobs} must be >= 1")
    return EngineSpec(args.engine, args.address, args.jobs, args.retries)


@contextlib.contextmanager
def held_engine(spec: EngineSpec | None) -> Iterator[EngineSpec]:
    """``spec`` itself, except dask without an address: a LocalCluster of ``spec.workers``
    single-threaded processes started here, yielded as its address, closed on exit."""
    spec = spec or EngineSpec()
    if spec.kind != "dask" or spec.address is not None:
        yield spec
        return
    cluster = start_local_cluster(spec.workers, spec.retries)
    try:
        yield EngineSpec("dask", cluster.scheduler_address, spec.workers, spec.retries, spec.timeout_s)
    finally:
        cluster.close()
