"""The CPU accounting and the row comparison of ``thermal-comp bench scale``."""
from __future__ import annotations

import math
import subprocess
import sys

from thermal_eval.bench.scale import TIMING_FIELDS, _cpu_snapshot, _strip, cpu_since

BURN_S = 0.3
# a child that spends BURN_S of its own CPU time, says so, then waits for a line on stdin
_BURN = ("import sys, time\n"
         f"while time.process_time() < {BURN_S}: pass\n"
         "print('burnt', flush=True)\n"
         "sys.stdin.readline()\n")


def _row(key, value):
    return {"key": key, "p99_lin_um": value, "p99": {"E_X0C": value}, "seconds": 1.0, "cpu_s": 0.5, "pid": 7}


def test_rows_compare_equal_with_nan_figures_and_other_timings():
    a = [_row("k1", math.nan), _row("k2", 1.5)]
    b = [{**_row("k2", 1.5), "seconds": 9.0, "pid": 8}, {**_row("k1", math.nan), "cpu_s": 3.0}]
    assert _strip(a) == _strip(b)                       # NaN == NaN, order and timings aside
    assert _strip(a) != _strip([_row("k1", math.nan), _row("k2", 1.6)])
    assert all(f not in line for line in _strip(a) for f in TIMING_FIELDS)


def test_cpu_since_counts_a_reaped_child_and_a_living_one():
    before = _cpu_snapshot()
    subprocess.run([sys.executable, "-c", _BURN], input="\n", text=True, check=True, timeout=60)
    assert cpu_since(before) >= BURN_S                  # started and reaped in between: RUSAGE_CHILDREN
    child = subprocess.Popen([sys.executable, "-c", _BURN], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        before = _cpu_snapshot()
        assert child.stdout.readline().strip() == "burnt"
        assert cpu_since(before) >= 0.5 * BURN_S        # alive at both ends: its delta (part burnt before)
        mid = _cpu_snapshot()
        assert cpu_since(mid) < BURN_S                  # a waiting child adds (almost) nothing
    finally:
        child.communicate("\n", timeout=60)
