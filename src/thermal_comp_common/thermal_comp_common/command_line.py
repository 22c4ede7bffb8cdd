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
