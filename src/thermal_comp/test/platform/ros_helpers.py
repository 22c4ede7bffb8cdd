"""Helpers for tests that run ROS 2 nodes in other processes."""
from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import time

PROCS = pathlib.Path(__file__).resolve().parent / "procs"


def spawn_test_node(script: str, namespace: str, *ros_args: str) -> subprocess.Popen:
    """Start test/platform/procs/<script>.py in its own process group, in `namespace`."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, str(PROCS / f"{script}.py"), "--ros-args",
                             "-r", f"__ns:={namespace}", *ros_args],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


def stop_process(p: subprocess.Popen, timeout: float = 10.0) -> str:
    """SIGINT, wait, kill if needed; return the process output."""
    if p.poll() is None:
        p.send_signal(2)
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    return p.stdout.read() if p.stdout else ""


def spin_until(executor, condition, timeout_s: float, what: str) -> None:
    """Spin `executor` until condition() holds; fail with `what` after timeout_s (a deadline, not a sleep)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        executor.spin_once(timeout_sec=0.05)
