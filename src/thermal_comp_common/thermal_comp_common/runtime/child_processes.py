"""Stopping a child process that may not stop: a signal, a bounded wait, then SIGKILL.

Tests, benchmarks and fault rows start nodes as separate processes and must end them without
waiting forever (a node that ignores or misses its stop signal). One definition of that sequence.
"""
from __future__ import annotations

import signal
import subprocess


def stop(proc: subprocess.Popen | None, sig: int = signal.SIGINT, timeout_s: float = 30.0) -> int | None:
    """Send ``sig`` to ``proc`` if it still runs, wait at most ``timeout_s``, then SIGKILL it.
    Returns its exit code (negative: the signal that ended it); None for no process."""
    if proc is None:
        return None
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()
