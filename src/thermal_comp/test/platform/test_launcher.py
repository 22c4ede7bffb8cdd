"""The launcher: a two-node cell as separate processes, inspection, restart, clean shutdown."""
from __future__ import annotations

import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time

import psutil
import pytest

from ros_helpers import PROCS

pytestmark = [pytest.mark.ros]
CELL = pathlib.Path(__file__).resolve().parent / "cells" / "two_nodes.yaml"
THERMAL_COMP = [sys.executable, "-m", "thermal_comp.cli"]


class LauncherProcess:
    """`thermal-comp launch` in a subprocess, its output collected line by line."""

    def __init__(self, *cells: str, extra: list[str] = ()):
        env = dict(os.environ, PYTHONPATH=str(PROCS), PYTHONUNBUFFERED="1")
        self.p = subprocess.Popen([*THERMAL_COMP, "launch", *cells, *extra], env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        self._cv = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.p.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                self._cv.notify_all()

    def wait_for(self, pattern: str, timeout: float = 30.0, start: int = 0) -> re.Match:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        with self._cv:
            while True:
                for line in self.lines[start:]:
                    m = rx.search(line)
                    if m:
                        return m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"launcher output never matched {pattern!r}:\n" + "\n".join(self.lines[-40:]))
                self._cv.wait(left)

    def pids(self) -> dict[str, int]:
        out = {}
        for line in self.lines:
            m = re.search(r"started (\S+) \(pid (\d+)\)", line)
            if m:
                out[m.group(1)] = int(m.group(2))
        return out

    def kill(self):
        if self.p.poll() is None:
            os.killpg(self.p.pid, signal.SIGKILL)
            self.p.wait()


def _cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([*THERMAL_COMP, *args], capture_output=True, text=True, timeout=timeout)


def _gone(pids, timeout=15.0) -> list[int]:
    deadline = time.monotonic() + timeout
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        if alive:
            psutil.wait_procs([psutil.Process(p) for p in alive if psutil.pid_exists(p)], timeout=0.2)
    return alive


def test_launch_cell_topics_restart_and_sigterm_leaves_nothing(tmp_path):
    run = LauncherProcess(str(CELL), extra=["--run-dir", str(tmp_path)])
    try:
        run.wait_for(r"started example/talker \(pid \d+\)")
        run.wait_for(r"started example/listener \(pid \d+\)")
        topics = _cli("topics", "-t", "--expect", "/example/temperatures", "--wait", "30")
        assert topics.returncode == 0, topics.stderr
        assert "/example/temperatures [thermal_comp_msgs/msg/TemperatureArray]" in topics.stdout
        nodes = _cli("nodes", "--expect", "/example/talker", "--expect", "/example/listener", "--wait", "30")
        assert nodes.returncode == 0, nodes.stderr
        # logs are prefixed with the cell and node
        run.wait_for(r"^\[example/listener\] received ambient=")
        echo = _cli("echo", "/example/temperatures", "--once", "--wait", "30")
        assert echo.returncode == 0, echo.stderr
        assert "sensor_ids: [ambient, spindle]" in echo.stdout
        # parameters came from the cell file
        assert (tmp_path / "example" / "talker.params.yaml").read_text().startswith("'/example/talker':")

        # kill -9 of a node: restarted by the launcher
        first = run.pids()["example/talker"]
        n_before = len(run.lines)
        os.kill(first, signal.SIGKILL)
        run.wait_for(r"example/talker exited with signal 9; restart 1/3", start=n_before)
        m = run.wait_for(r"started example/talker \(pid (\d+)\)", start=n_before)
        assert int(m.group(1)) != first
        n_before = len(run.lines)
        run.wait_for(r"^\[example/listener\] received", start=n_before)

        pids = list(run.pids().values()) + [int(m.group(1))]
        run.p.send_signal(signal.SIGTERM)
        assert run.p.wait(timeout=30) == 0
        assert _gone(pids) == [], "processes left behind after SIGTERM"
        leftovers = [p.pid for p in psutil.process_iter(["cmdline"])
                     if any(str(tmp_path) in a for a in (p.info["cmdline"] or []))]
        assert leftovers == [], f"processes of this run still alive: {leftovers}"
    finally:
        run.kill()


def test_children_die_with_a_killed_launcher(tmp_path):
    run = LauncherProcess(str(CELL), extra=["--run-dir", str(tmp_path), "--no-restart"])
    try:
        run.wait_for(r"started example/talker")
        run.wait_for(r"started example/listener")
        pids = list(run.pids().values())
        os.kill(run.p.pid, signal.SIGKILL)  # no chance to clean up: PDEATHSIG must do it
        run.p.wait(timeout=10)
        assert _gone(pids) == [], "node processes outlived a kill -9 of the launcher"
    finally:
        run.kill()


def test_two_cells_in_their_own_domains(tmp_path):
    base = CELL.read_text()
    did = (int(os.environ["ROS_DOMAIN_ID"]) + 100) % 200 + 1
    a = tmp_path / "a.yaml"
    a.write_text(base.replace("cell: example", f"cell: cell_a\ndomain_id: {did}"))
    b = tmp_path / "b.yaml"
    b.write_text(base.replace("cell: example", "cell: cell_b"))
    run = LauncherProcess(str(a), str(b), extra=["--run-dir", str(tmp_path / "run")])
    try:
        run.wait_for(r"^\[cell_a/listener\] received")
        run.wait_for(r"^\[cell_b/listener\] received")
        own = _cli("topics", "--expect", "/cell_b/temperatures", "--wait", "30")
        assert own.returncode == 0 and "/cell_a/temperatures" not in own.stdout
        other = _cli("topics", "--domain-id", str(did), "--expect", "/cell_a/temperatures", "--wait", "30")
        assert other.returncode == 0, other.stderr
        assert "/cell_b/temperatures" not in other.stdout
        run.p.send_signal(signal.SIGINT)
        assert run.p.wait(timeout=30) == 0
    finally:
        run.kill()


@pytest.mark.parametrize("text, expected", [
    ("cell: x\nnodes: []\n", "nodes: expected a non-empty list"),
    ("cell: 1x\nnodes: [{name: a, module: m}]\n", "cell: expected a name"),
    ("cell: x\ndomain_id: 999\nnodes: [{name: a, module: m}]\n", "domain_id: expected an integer in [0, 232], got 999"),
    ("cell: x\nnodes: [{name: a, package: thermal_twin, executable: nope}]\n",
     "nodes[0].executable: 'nope' is not an executable of the installed package 'thermal_twin'"),
    ("cell: x\nnodes: [{name: a, module: m, parameters: {rate: [1, a]}}]\n", "nodes[0].parameters.rate: a list parameter"),
    ("cell: x\nnodes: [{name: a, module: m, restrat: true}]\n", "nodes[0].restrat: unknown key"),
    ("cell: x\nnodes: [{name: a, module: m}, {name: a, module: n}]\n", "nodes[1].name: duplicate node name 'a'"),
    ("cell: x\nnodes: [{name: a, module: m, restart: {backoff_s: -1}}]\n", "nodes[0].restart.backoff_s: expected seconds"),
    ("cell: [x\n", "not valid YAML"),
])
def test_bad_cell_file_gives_one_clear_line(tmp_path, text, expected):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    r = _cli("launch", str(f), timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"thermal-comp launch: {f}: ")
    assert expected in lines[0]


def test_every_subcommand_has_help():
    top = _cli("--help")
    assert top.returncode == 0
    names = re.findall(r"^  (\S+)\s", top.stdout, flags=re.M)
    assert {"launch", "topics", "echo", "nodes"} <= set(names)
    for name in names:
        r = _cli(name, "--help")
        assert r.returncode == 0, f"thermal-comp {name} --help failed:\n{r.stderr}"
        assert "usage:" in r.stdout
