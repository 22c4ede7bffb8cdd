"""One cell, one owner: a second launch of a running cell (same namespace and domain) is refused
naming the running one (pid, start time); the lock of a dead process is taken over with a warning."""
from __future__ import annotations

import io
import os
import signal
import subprocess
import sys

import pytest

from thermal_comp.cell import launcher as launcher_mod
from thermal_comp.cell.cell_lock import CellLockError, acquire_cell_lock, lock_path
from thermal_comp.cell.config import parse_cell
from thermal_comp.cell.launcher import Launcher

_HOLDER = ("import sys, pathlib\n"
           "from thermal_comp.cell.cell_lock import acquire_cell_lock\n"
           "lock = acquire_cell_lock(7, '/held_cell', pathlib.Path(sys.argv[1]))\n"
           "print('held', flush=True)\n"
           "sys.stdin.read()\n")


@pytest.fixture
def holder(tmp_path):
    """Another process holding the lock of /held_cell on domain 7 in ``tmp_path``."""
    p = subprocess.Popen([sys.executable, "-c", _HOLDER, str(tmp_path)], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    yield p
    if p.poll() is None:
        p.kill()
    p.wait()


def test_a_second_owner_is_refused_naming_the_running_one(tmp_path, holder):
    with pytest.raises(CellLockError, match=rf"cell /held_cell on ROS_DOMAIN_ID 7 runs already "
                                            rf"\(pid {holder.pid}, started \d{{4}}-\d\d-\d\d "):
        acquire_cell_lock(7, "/held_cell", tmp_path)
    other = acquire_cell_lock(8, "/held_cell", tmp_path)     # another domain: another cell
    assert other.warning == ""
    other.release()


def test_the_lock_of_a_dead_process_is_taken_over_with_a_warning(tmp_path, holder):
    holder.send_signal(signal.SIGKILL)     # no clean-up: the file still names it
    holder.wait()
    lock = acquire_cell_lock(7, "/held_cell", tmp_path)
    assert f"left by pid {holder.pid}" in lock.warning and "no longer runs" in lock.warning
    assert lock_path(7, "/held_cell", tmp_path).read_text().split()[0] == str(os.getpid())
    lock.release()
    again = acquire_cell_lock(7, "/held_cell", tmp_path)     # a clean release leaves nothing stale
    assert again.warning == ""
    again.release()


def _cell(tmp_path, name: str):
    (tmp_path / "wait_stdin.py").write_text("import sys\nsys.stdin.read()\n")
    doc = {"cell": name, "nodes": [{"name": "idle", "module": "wait_stdin",
                                    "env": {"PYTHONPATH": str(tmp_path)}, "restart": {"enabled": False}}]}
    return parse_cell(doc, source="test cell", resolve=False)


def test_a_second_launcher_of_a_running_cell_starts_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr("thermal_comp.cell.cell_lock.LOCK_DIR", tmp_path / "locks")
    name = f"lockcell{os.getpid()}"
    first = Launcher([_cell(tmp_path, name)], run_dir=tmp_path / "run1", output=io.StringIO(), grace_s=2.0)
    first.start()
    try:
        second = Launcher([_cell(tmp_path, name)], run_dir=tmp_path / "run2", output=io.StringIO())
        with pytest.raises(CellLockError, match=rf"cell /{name} on ROS_DOMAIN_ID \d+ runs already \(pid {os.getpid()},"):
            second.start()
        assert all(mp.popen is None for mp in second.processes)
    finally:
        first.request_stop()
        first.stop()
    third = Launcher([_cell(tmp_path, name)], run_dir=tmp_path / "run3", output=io.StringIO(), grace_s=2.0)
    third.start()       # the first one stopped: its lock is free again
    third.request_stop()
    third.stop()


def test_launch_command_refuses_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("thermal_comp.cell.cell_lock.LOCK_DIR", tmp_path / "locks")
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text("cell: cmdcell\ndomain_id: 9\nnodes: [{name: idle, module: json.tool}]\n")
    held = acquire_cell_lock(9, "/cmdcell")
    try:
        assert launcher_mod.main([str(cell_file), "--run-dir", str(tmp_path / "run")]) == 2
    finally:
        held.release()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thermal-comp launch: cell /cmdcell on ROS_DOMAIN_ID 9 "
                                               f"runs already (pid {os.getpid()}"), err


@pytest.mark.ros
def test_a_second_launch_command_is_refused_and_a_killed_ones_lock_taken_over(tmp_path):
    from test_launcher import CELL, THERMAL_COMP, LauncherProcess
    first = LauncherProcess(str(CELL), extra=["--run-dir", str(tmp_path / "run1")])
    try:
        first.wait_for(r"started example/talker \(pid \d+\)")
        second = subprocess.run([*THERMAL_COMP, "launch", str(CELL), "--run-dir", str(tmp_path / "run2")],
                                capture_output=True, text=True, timeout=60)
        assert second.returncode == 2, second.stdout + second.stderr
        err = second.stderr.strip().splitlines()
        assert len(err) == 1 and f"cell /example on ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']} runs already " \
                                 f"(pid {first.p.pid}, started " in err[0], err
        assert "started example/" not in second.stdout
        first.kill()        # kill -9: the lock file still names it, the kernel freed the lock
        third = LauncherProcess(str(CELL), extra=["--run-dir", str(tmp_path / "run3")])
        try:
            third.wait_for(rf"WARNING cell /example on ROS_DOMAIN_ID \d+: taking over the lock .* left by "
                           rf"pid {first.p.pid}, started .*, which no longer runs")
            third.wait_for(r"started example/talker")
            third.p.send_signal(signal.SIGTERM)
            assert third.p.wait(timeout=30) == 0
        finally:
            third.kill()
    finally:
        first.kill()
