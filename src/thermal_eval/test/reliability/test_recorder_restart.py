"""A recorder restarted by the launcher after a crash must record again, not refuse its folder."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from thermal_comp_common.bag_reader import read_bag

pytestmark = [pytest.mark.ros]


def _recorder(out) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "thermal_comp.bag_recorder_node", "--ros-args",
                             "-r", "__ns:=/restart_test", "-p", f"output:={out}"],
                            env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_for_line(proc, text, timeout_s=60.0) -> list[str]:
    import selectors
    import time
    lines = []
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sel.select(timeout=0.5):
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if text in line:
                return lines
    raise AssertionError(f"never printed {text!r}:\n{''.join(lines)}")


def test_restarted_recorder_continues_in_a_new_bag_and_keeps_the_old(tmp_path):
    out = tmp_path / "bag"
    first = _recorder(out)
    try:
        _wait_for_line(first, "recording")
    finally:
        first.send_signal(signal.SIGKILL)   # a crash: no clean close
        first.wait(timeout=30)
    assert out.is_dir()
    second = _recorder(out)
    try:
        _wait_for_line(second, "recording continues in")
    finally:
        second.send_signal(signal.SIGINT)
        second.wait(timeout=30)
    assert second.returncode == 0
    assert (tmp_path / "bag.2" / "metadata.yaml").is_file(), "the restarted recorder wrote no bag"
    read_bag(out)                # the crashed bag is left as it was and still opens
    read_bag(tmp_path / "bag.2")
