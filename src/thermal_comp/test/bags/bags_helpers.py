"""Shared helpers of the bag tests: small recordings and process control."""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np

from thermal_comp_common.recording_csv import write_recording_csv


def small_recording_csv(path: pathlib.Path, rows: int = 40, seed: int = 3) -> pathlib.Path:
    """A twin-like recording: 3 sensors (one NaN), 2 errors, C-axis speed and coolant."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 60.0
    cols = {
        "c_speed_rpm": np.where((t // 600) % 2 == 1, 800.0, 0.0),
        "coolant_on": np.where(t > 900, 1.0, 0.0),
        "ambient_c": 20.0 + 0.01 * np.arange(rows) + rng.normal(0, 0.02, rows),
        "c_motor_c": 25.0 + np.cumsum(rng.normal(0.05, 0.05, rows)),
        "ws_mwf_c": 21.0 + rng.normal(0, 0.1, rows),
        "E_X0C": np.cumsum(rng.normal(0.1, 0.3, rows)),
        "E_A0C": np.cumsum(rng.normal(0.0, 0.2, rows)),
    }
    cols["ws_mwf_c"][5] = np.nan
    write_recording_csv(path, t, cols)
    return path


def env() -> dict:
    e = dict(os.environ)
    e["PYTHONUNBUFFERED"] = "1"
    return e


def spawn(args: list[str], **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *args], env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, **kw)


def wait_for(cond, timeout: float, what: str, poll: float = 0.02):
    """Wait until ``cond()`` is truthy (returns it) or fail naming ``what``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = cond()
        if v:
            return v
        time.sleep(poll)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def stop(proc: subprocess.Popen, sig=signal.SIGINT, timeout: float = 20.0) -> str:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""
