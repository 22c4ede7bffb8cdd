"""The demo's supervision counts a node's memory and CPU time over its whole process tree, from
one pass over the host's processes shared by every node."""
from __future__ import annotations

import subprocess
import sys

import psutil

from thermal_comp.demo.graph import _children_map, _usage_tree

# a parent that burns some CPU and starts a child holding 64 MiB, both then wait for stdin
_PARENT = ("import subprocess, sys\n"
           "child = subprocess.Popen([sys.executable, '-c', "
           "'import sys; b = bytearray(64 << 20); print(1, flush=True); sys.stdin.read()'], "
           "stdout=subprocess.PIPE, stdin=subprocess.PIPE)\n"
           "child.stdout.readline(); sum(i * i for i in range(3_000_000)); print(child.pid, flush=True)\n"
           "sys.stdin.read(); child.stdin.close(); child.wait()\n")


def test_usage_covers_the_whole_tree():
    parent = subprocess.Popen([sys.executable, "-c", _PARENT], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        child_pid = int(parent.stdout.readline())
        children = _children_map()
        assert child_pid in children[parent.pid]
        mem_tree, cpu_tree = _usage_tree(parent.pid, children)
        alone = psutil.Process(parent.pid)
        mem_parent = alone.memory_info().rss / 2**20
        assert mem_tree > mem_parent + 60          # the child's 64 MiB counted
        assert cpu_tree >= sum(alone.cpu_times()[:2]) > 0.05
        assert _usage_tree(parent.pid)[0] > mem_parent + 60    # its own map when none is given
    finally:
        parent.stdin.close()
        parent.wait(timeout=30)


def test_a_process_gone_counts_nothing():
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    assert _usage_tree(int(done.stdout)) == (0.0, 0.0)
