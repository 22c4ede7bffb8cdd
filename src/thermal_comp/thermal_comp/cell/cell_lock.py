"""One cell, one owner: an exclusive lock per (ROS_DOMAIN_ID, namespace) on this machine.

Two launches of the same cell would run two graphs that acknowledge each other's instants and
write to the same bags and CNC. The launcher takes an exclusive ``flock`` on a file per (domain
id, namespace) in :data:`LOCK_DIR` (as :mod:`thermal_comp_common.runtime.domain_ids` holds its
ids); the kernel releases it when the holding process ends, however it ends. The file records
the holder's pid and start time, so a refused launch can name the running one; a file left by
a dead process holds no lock and is taken over with a warning naming that process.
"""
from __future__ import annotations

import fcntl
import os
import pathlib
import tempfile
import time
from dataclasses import dataclass
from typing import TextIO

LOCK_DIR = pathlib.Path(tempfile.gettempdir()) / "thermal_comp_cell_locks"


class CellLockError(RuntimeError):
    """The cell runs already (the message names its pid and start time)."""


def lock_path(domain_id: int, namespace: str, lock_dir: pathlib.Path | None = None) -> pathlib.Path:
    """The lock file of a cell: one per (domain id, namespace)."""
    safe = namespace.strip("/").replace("/", "__") or "_root"
    return (lock_dir or LOCK_DIR) / f"domain{int(domain_id)}_{safe}.lock"


def _holder_text(text: str) -> str:
    """'pid P, started T' from a lock file's 'pid start_epoch_s' line ('unknown' if unreadable)."""
    parts = text.split()
    try:
        pid, started = int(parts[0]), float(parts[1])
    except (IndexError, ValueError):
        return "an unknown process"
    return f"pid {pid}, started {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(started))}"


@dataclass
class CellLock:
    """A held lock; :meth:`release` (or the end of the process) frees it."""

    path: pathlib.Path
    file: TextIO
    warning: str = ""      # set when a dead process's file was taken over

    def release(self) -> None:
        """Free the lock; the emptied file tells the next launch that this one ended cleanly."""
        if not self.file.closed:
            self.file.seek(0)
            self.file.truncate()
            self.file.close()     # closing the descriptor drops the flock


def acquire_cell_lock(domain_id: int, namespace: str, lock_dir: pathlib.Path | None = None) -> CellLock:
    """Hold the lock of cell ``namespace`` on ``domain_id``; CellLockError naming the running
    launch (pid and start time) when another process holds it."""
    path = lock_path(domain_id, namespace, lock_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    f = open(path, "a+")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        holder = _holder_text(f.read())
        f.close()
        raise CellLockError(f"cell {namespace} on ROS_DOMAIN_ID {domain_id} runs already ({holder}; "
                            f"lock {path}): stop it first, or use another namespace or domain") from None
    f.seek(0)
    previous = f.read().strip()
    warning = ""
    if previous:
        warning = (f"cell {namespace} on ROS_DOMAIN_ID {domain_id}: taking over the lock {path} "
                   f"left by {_holder_text(previous)}, which no longer runs")
    f.seek(0)
    f.truncate()
    f.write(f"{os.getpid()} {time.time():.3f}\n")
    f.flush()
    return CellLock(path, f, warning)
