"""Running a subcommand's work once its arguments are parsed.

Every ``thermal-comp`` subcommand has a light parser module (argparse and the standard library)
and a work module with the heavy imports. The parser's ``main`` hands the work's ``"module:function"`` and the
parsed arguments to :func:`run_parsed`, so ``--help`` and argument errors never
import the work, and the one deferred import of the whole command line is here.
"""
from __future__ import annotations

import importlib
from typing import Any


def run_parsed(work: str, *args: Any) -> int:
    """Import ``work`` (``"package.module:function"``), call it with ``args`` (the parsed
    arguments, or what the parser made of them), return its exit code."""
    module, _, function = work.partition(":")
    if not module or not function:
        raise ValueError(f"work {work!r}: expected 'package.module:function'")
    return int(getattr(importlib.import_module(module), function)(*args) or 0)


def add_sample_period_argument(ap) -> None:
    """The one ``--sample-period-s S`` of every command that reads recordings (``ap``: a parser or
    an argument group): a CSV without a ``time_s`` column has row i at i x S seconds. A CSV with
    a time column, or a bag, given a period is refused (its own time wins, never silently)."""
    ap.add_argument("--sample-period-s", type=float, metavar="S", default=None,
                    help="a CSV without a time_s column: row i is at i x S seconds (every recording "
                         "read; refused for a CSV with a time_s column or a bag)")
