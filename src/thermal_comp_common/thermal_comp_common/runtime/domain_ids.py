"""Claim a ROS_DOMAIN_ID that no other thermal-comp run on this machine holds.

A run (demo, benchmark, test session) that must not see other graphs takes an id by an
exclusive ``flock`` on a file per id; the lock is released when the process ends. Ids are
taken from 1..101: ROS 2 documents 0..101 as the range safe on Linux (higher ids reach the
kernel's ephemeral ports), and 0 is left to the default graph of every other ROS user.
"""
from __future__ import annotations

import fcntl
import os
import pathlib
import tempfile

LOCK_DIR = pathlib.Path(tempfile.gettempdir()) / "thermal_comp_domain_locks"
_held: list = []


SAFE_DOMAIN_IDS = range(0, 102)   # ROS 2's safe ROS_DOMAIN_ID range on Linux


def claim_domain_id(first: int = 1, last: int = 101) -> int:
    """Return a free id in [first, last] and hold it for the life of this process."""
    LOCK_DIR.mkdir(exist_ok=True)
    span = last - first + 1
    start = os.getpid() % span
    for k in range(span):
        did = first + (start + k) % span
        f = open(LOCK_DIR / f"{did}.lock", "w")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        _held.append(f)
        return did
    raise RuntimeError(f"no free ROS_DOMAIN_ID in {first}..{last}")
