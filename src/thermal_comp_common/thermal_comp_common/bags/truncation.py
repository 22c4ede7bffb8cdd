"""``--allow-truncated``: whether a command reads a bag that ends early (light: no numpy, no bag code).

A bag cut by a crash, damaged, or closed incomplete by its recorder on a write error holds only
the start of a recording; :func:`thermal_comp_common.bags.recording.load_recording` refuses it,
naming where it ends, unless the command runs within :func:`truncated_bags_allowed`. The
permission travels in the environment so that worker processes a command starts share it.
"""
from __future__ import annotations

import argparse
import contextlib
import os

#: "1": this process and the workers it starts read a bag that ends early up to where it ends
ALLOW_TRUNCATED_ENV = "THERMAL_COMP_ALLOW_TRUNCATED"


def add_allow_truncated_argument(ap: argparse.ArgumentParser) -> None:
    """The ``--allow-truncated`` flag of a command that reads recordings."""
    ap.add_argument("--allow-truncated", action="store_true",
                    help="use a bag that ends early (cut by a crash, damaged, or closed incomplete on a "
                         "write error) up to where it ends, with a warning; default: refused, naming where")


def truncated_allowed() -> bool:
    """Whether this process may read a bag that ends early."""
    return os.environ.get(ALLOW_TRUNCATED_ENV) == "1"


@contextlib.contextmanager
def truncated_bags_allowed(allowed: bool = True):
    """Within the block (and in worker processes started in it) a bag that ends early is read up
    to where it ends instead of refused, when ``allowed``."""
    before = os.environ.get(ALLOW_TRUNCATED_ENV)
    if allowed:
        os.environ[ALLOW_TRUNCATED_ENV] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(ALLOW_TRUNCATED_ENV, None)
        else:
            os.environ[ALLOW_TRUNCATED_ENV] = before
