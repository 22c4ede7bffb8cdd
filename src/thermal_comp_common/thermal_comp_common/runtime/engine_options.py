"""The task engine's command-line options, said once, and one engine held for a whole run.

``thermal-comp diagnose`` and ``calibrate`` (and any later command whose work is many
independent tasks) take ``--engine local|dask --address tcp://HOST:PORT --jobs N
--retries N`` with the meaning ``thermal-comp sweep`` gives them (``--workers`` is accepted
for ``--jobs``); every command's ``--jobs`` is :func:`add_jobs_argument` with one default,
:func:`default_jobs`. :func:`held_engine` serves a run that maps tasks several times (a diagnosis:
channel analysis, screening and fitting of every round, the out-of-vocabulary step):
``--engine dask`` without an address starts ONE LocalCluster for the whole run, instead of
one per map, and tears it down at the end. See docs/distributed.md.
"""
from __future__ import annotations

import argparse
import contextlib
from typing import Iterator

from thermal_comp_common.runtime.task_engine import (ENGINES, EngineSpec, TaskEngineError, default_workers,
                                                     start_local_cluster)


def default_jobs() -> int:
    """The one default of every command's ``--jobs``: all the cores this process may use but one
    (the machine stays usable while a long run works), at least 1."""
    return max(1, default_workers() - 1)


def add_jobs_argument(ap, what: str = "tasks") -> None:
    """The one ``--jobs`` (alias ``--workers``) option, default :func:`default_jobs`; ``ap`` is a
    parser or an argument group; ``what`` names the tasks."""
    n = default_jobs()
    ap.add_argument("--jobs", "--workers", dest="jobs", type=int, default=n,
                    help=f"processes of the local pool running the {what}, or the size of the dask LocalCluster "
                         f"started when --engine dask has no --address (default {n}: all cores but one)")


def add_engine_arguments(ap: argparse.ArgumentParser, what: str = "tasks") -> None:
    """Add ``--engine --address --jobs/--workers --retries`` to ``ap``; ``what`` names the tasks."""
    g = ap.add_argument_group("task engine (docs/distributed.md)")
    g.add_argument("--engine", choices=ENGINES, default="local",
                   help=f"where the {what} run (default: local; one process with --jobs 1)")
    g.add_argument("--address", default=None, metavar="tcp://HOST:PORT",
                   help="the dask scheduler of a running cluster (with --engine dask)")
    add_jobs_argument(g, what)
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
