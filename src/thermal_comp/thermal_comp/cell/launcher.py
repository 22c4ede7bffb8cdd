"""Start the nodes of one or more machine cells as separate processes (the missing ros2 launch).

``thermal-comp launch CELL.yaml [CELL.yaml ...]``: every node runs as its own process
(``python -m MODULE --ros-args ...``) in the cell's namespace, with its parameters from the
cell file (written to a ROS 2 parameters file) and the cell's ROS_DOMAIN_ID. Output lines are
prefixed with ``[cell/node]`` and also kept in a log file per node. A node that crashes is
restarted when its restart policy says so (with exponential back-off, up to a maximum); a
node that crashes (non-zero exit) and is not restarted (restart off, or its limit reached)
ends the run: one line names it and its exit, every node is stopped, ``run`` returns 1. A node
that exits 0 has finished its work and the others keep running.
Managed (lifecycle) nodes (cell key ``lifecycle``, or a module that declares
``LIFECYCLE_NODE = True``) are driven through configure and activate after every start and
through deactivate before a clean stop (:mod:`thermal_comp.cell.lifecycle_driver`, in the
cell's environment, each transition with the node's deadline); a transition that fails or
hangs is one error line naming the node, the node is stopped and not restarted, and
``run`` exits 1. Ctrl-C or SIGTERM stops every process: SIGINT first, SIGKILL after the
grace time, so no process is left behind; children also receive SIGTERM if the launcher
itself dies. A cell runs once: a second launch of the same namespace on the same ROS_DOMAIN_ID
is refused with one line naming the running launch (:mod:`thermal_comp.cell.cell_lock`).
A node's environment may set ``THERMAL_COMP_NICE`` (0-19): its process starts at
that niceness (lower priority; raising it would need root), so that observers (recorder, viewer,
probe cycle between probings) yield the cores to the control path in a cell.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, TextIO

from thermal_comp.cell.cell_lock import CellLock, CellLockError, acquire_cell_lock
from thermal_comp.cell.config import CellConfig, CellConfigError, NodeSpec, load_cell, parameters_file_text
from thermal_comp_common.runtime.dds_transport import cell_process_env

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


#: a node's environment variable: the niceness (0-19) its process starts at
NICE_ENV = "THERMAL_COMP_NICE"


def node_niceness(label: str, env: dict[str, str]) -> int:
    """The niceness ``env`` asks for (0 when unset); CellConfigError naming the node and value."""
    text = env.get(NICE_ENV, "").strip()
    if not text:
        return 0
    try:
        nice = int(text)
    except ValueError:
        nice = -1
    if not 0 <= nice <= 19:
        raise CellConfigError(f"{label}: env {NICE_ENV}={text!r} is not a niceness 0-19 "
                              f"(only lowering a node's priority needs no privilege)")
    return nice


def _child_setup(nice: int) -> Callable[[], None]:
    def setup() -> None:  # runs in the child between fork and exec, after its setsid
        _die_with_parent()
        if nice:
            os.nice(nice)
            # with autogroup scheduling (Linux default) every session is a group of its own and
            # a task's niceness only weighs inside its group: the new session's group is lowered
            try:
                with open("/proc/self/autogroup", "w") as f:
                    f.write(str(nice))
            except OSError:
                pass           # no autogroup: the niceness above is all there is
    return setup


@dataclass
class ManagedProcess:
    """One node process of a cell, with its restart bookkeeping."""

    cell: CellConfig
    node: NodeSpec
    argv: list[str]
    env: dict[str, str]
    log_path: pathlib.Path
    popen: subprocess.Popen | None = None
    restarts: int = 0
    next_start: float | None = None      # monotonic time of a pending restart
    exit_codes: list[int] = field(default_factory=list)
    nice: int = 0                        # niceness the process starts at (NICE_ENV)
    gave_up: bool = False
    lifecycle: str = ""                  # "", "activating", "active", "failed"
    lifecycle_error: str = ""
    _reader: threading.Thread | None = None
    _driver: threading.Thread | None = None

    @property
    def full_name(self) -> str:
        return f"{self.cell.namespace}/{self.node.name}"

    @property
    def label(self) -> str:
        return f"{self.cell.cell}/{self.node.name}"

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen is not None else None

    def running(self) -> bool:
        return self.popen is not None and self.popen.poll() is None


class Launcher:
    """Runs cells; usable from the command line and as a library (tests, demo)."""

    def __init__(self, cells: list[CellConfig], run_dir: str | pathlib.Path | None = None,
                 output: TextIO | None = None, restart_override: bool | None = None,
                 grace_s: float = 5.0, on_line: Callable[[str, str], None] | None = None):
        names = [c.cell for c in cells]
        dupes = {n for n in names if names.count(n) > 1}
        if dupes:
            raise CellConfigError(f"cell name(s) {sorted(dupes)} used by more than one cell file")
        self.cells = cells
        self.run_dir = pathlib.Path(run_dir or tempfile.mkdtemp(prefix="thermal_comp_run_"))
        self.output = output if output is not None else sys.stdout
        self.grace_s = grace_s
        self.on_line = on_line
        self._out_lock = threading.Lock()
        self._stopping = threading.Event()
        self.processes: list[ManagedProcess] = []
        self._locks: list[CellLock] = []
        for cell in cells:
            cell_dir = self.run_dir / cell.cell
            cell_dir.mkdir(parents=True, exist_ok=True)
            for node in cell.nodes:
                if restart_override is not None:
                    node.restart = type(node.restart)(restart_override, node.restart.max_restarts,
                                                      node.restart.backoff_s)
                params_file = cell_dir / f"{node.name}.params.yaml"
                params_file.write_text(parameters_file_text(cell, node))
                argv = [sys.executable, "-m", node.module, *node.args, "--ros-args",
                        "-r", f"__ns:={cell.namespace}", "-r", f"__node:={node.name}",
                        "--params-file", str(params_file)]
                env = dict(os.environ)
                env.update(cell.env)
                env.update(node.env)
                env["PYTHONUNBUFFERED"] = "1"
                env.setdefault("ROS_LOG_DIR", str(self.run_dir / "ros_logs"))
                if cell.domain_id is not None:
                    env["ROS_DOMAIN_ID"] = str(cell.domain_id)
                env = cell_process_env(env, self.run_dir)  # UDP only (survives kill -9); LOCALHOST: on lo
                self.processes.append(ManagedProcess(cell, node, argv, env, cell_dir / f"{node.name}.log",
                                                     nice=node_niceness(f"{cell.cell}/{node.name}", env)))

    # ----------------------------------------------------------------------------------
    def _emit(self, label: str, line: str) -> None:
        with self._out_lock:
            self.output.write(f"[{label}] {line}\n")
            self.output.flush()
        if self.on_line is not None:
            self.on_line(label, line)

    def _pump(self, mp: ManagedProcess, popen: subprocess.Popen) -> None:
        with open(mp.log_path, "a", buffering=1) as log:
            assert popen.stdout is not None
            for raw in popen.stdout:
                line = raw.rstrip("\n")
                log.write(line + "\n")
                self._emit(mp.label, line)

    def _spawn(self, mp: ManagedProcess) -> None:
        mp.popen = subprocess.Popen(mp.argv, env=mp.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, text=True, bufsize=1,
                                    start_new_session=True, preexec_fn=_child_setup(mp.nice))
        mp.next_start = None
        mp._reader = threading.Thread(target=self._pump, args=(mp, mp.popen), daemon=True,
                                      name=f"log-{mp.label}")
        mp._reader.start()
        self._emit("launch", f"started {mp.label} (pid {mp.popen.pid}): python -m {mp.node.module}"
                   + (f" at nice {mp.nice}" if mp.nice else ""))
        if mp.node.lifecycle:
            mp.lifecycle = "activating"
            mp._driver = threading.Thread(target=self._bring_up, args=(mp, mp.popen), daemon=True,
                                          name=f"lifecycle-{mp.label}")
            mp._driver.start()

    # ---------------------------------------------------------------------------------- lifecycle
    def _transition(self, mp: ManagedProcess, transitions: list[str]) -> str:
        """Run the lifecycle driver for ``mp``; return "" on success, else the error line."""
        timeout = mp.node.lifecycle_timeout_s
        argv = [sys.executable, "-m", "thermal_comp.cell.lifecycle_driver", "--timeout", f"{timeout:g}",
                mp.full_name, *transitions]
        try:   # the driver has its own deadlines; this one covers a driver that hangs itself
            done = subprocess.run(argv, env=mp.env, capture_output=True, text=True,
                                  timeout=timeout * (len(transitions) + 1) + 30.0,
                                  stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            return f"{mp.label}: lifecycle {' '.join(transitions)} hung (no answer within the deadline)"
        if done.returncode != 0:
            lines = (done.stderr.strip() or done.stdout.strip() or f"exit code {done.returncode}").splitlines()
            return f"{mp.label}: {lines[-1]}"
        return ""

    def _bring_up(self, mp: ManagedProcess, popen: subprocess.Popen) -> None:
        error = self._transition(mp, ["configure", "activate"])
        if popen is not mp.popen or self._stopping.is_set():
            return            # restarted or stopping meanwhile: this attempt no longer matters
        if not error:
            mp.lifecycle = "active"
            self._emit("launch", f"{mp.label}: configured and active")
            return
        mp.lifecycle, mp.lifecycle_error, mp.gave_up = "failed", error, True
        self._emit("launch", f"ERROR {error}; stopping {mp.label} (no restart)")
        try:
            os.killpg(popen.pid, signal.SIGINT)
        except ProcessLookupError:
            pass

    def _bring_down(self) -> None:
        """Deactivate every active managed node (in parallel, each with its deadline)."""
        active = [mp for mp in self.processes if mp.lifecycle == "active" and mp.running()]
        errors: dict[str, str] = {}

        def one(mp):
            errors[mp.label] = self._transition(mp, ["deactivate"])
        threads = [threading.Thread(target=one, args=(mp,), daemon=True) for mp in active]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for mp in active:
            if errors.get(mp.label):
                self._emit("launch", f"ERROR {errors[mp.label]}")
            else:
                mp.lifecycle = "inactive"
                self._emit("launch", f"{mp.label}: deactivated")

    @property
    def lifecycle_failures(self) -> list[str]:
        return [mp.lifecycle_error for mp in self.processes if mp.lifecycle == "failed"]

    def domain_id(self, cell: CellConfig) -> int:
        """The ROS_DOMAIN_ID the cell's processes run on (cell file, else its env, else ours)."""
        if cell.domain_id is not None:
            return cell.domain_id
        text = cell.env.get("ROS_DOMAIN_ID", os.environ.get("ROS_DOMAIN_ID", "")).strip()
        return int(text) if text.isdigit() else 0

    def lock_cells(self) -> None:
        """Hold each cell's lock (CellLockError naming the running launch; none held then);
        :meth:`start` does it if not done before, :meth:`stop` releases them."""
        if self._locks:
            return
        try:
            for cell in self.cells:
                lock = acquire_cell_lock(self.domain_id(cell), cell.namespace)
                self._locks.append(lock)
                if lock.warning:
                    self._emit("launch", f"WARNING {lock.warning}")
        except CellLockError:
            self._unlock_cells()
            raise

    def _unlock_cells(self) -> None:
        for lock in self._locks:
            lock.release()
        self._locks.clear()

    def start(self) -> None:
        """Start every node; CellLockError (nothing started) when a cell runs already."""
        self.lock_cells()
        for mp in self.processes:
            self._spawn(mp)

    def poll(self) -> bool:
        """Handle exits and due restarts; return True while any process runs or may restart."""
        now = time.monotonic()
        alive = False
        for mp in self.processes:
            if mp.popen is None:
                continue
            code = mp.popen.poll()
            if code is None:
                alive = True
                continue
            if mp._reader is not None:  # an exit not handled yet
                mp._reader.join(timeout=2.0)
                mp._reader = None
                mp.exit_codes.append(code)
                how = f"signal {-code}" if code < 0 else f"code {code}"
                policy = mp.node.restart
                if self._stopping.is_set() or mp.lifecycle == "failed":
                    pass
                elif code != 0 and policy.enabled and mp.restarts < policy.max_restarts:
                    delay = policy.backoff_s * (2 ** mp.restarts)
                    mp.next_start = now + delay
                    self._emit("launch", f"{mp.label} exited with {how}; restart "
                               f"{mp.restarts + 1}/{policy.max_restarts} in {delay:.1f} s")
                elif code != 0:
                    mp.gave_up = policy.enabled
                    self.ended_by = self.ended_by or mp.label
                    why = "restart limit reached" if mp.gave_up else "restart off"
                    self._emit("launch", f"{mp.label} exited with {how} and is not restarted ({why}): "
                               f"the cell cannot go on without it; stopping every node")
                else:
                    self._emit("launch", f"{mp.label} exited with {how}")
                if mp.lifecycle != "failed":
                    mp.lifecycle = "" if mp.node.lifecycle else mp.lifecycle
            if mp.next_start is not None and not self._stopping.is_set():
                alive = True
                if now >= mp.next_start:
                    mp.restarts += 1
                    self._spawn(mp)
        return alive

    def stop(self) -> None:
        """Stop every process: managed nodes are deactivated first, then SIGINT, then SIGKILL
        after the grace time (whole process groups)."""
        if not self._brought_down:
            self._brought_down = True
            self._bring_down()
        self._stopping.set()
        for mp in self.processes:
            mp.next_start = None
            if mp.running():
                try:
                    os.killpg(mp.popen.pid, signal.SIGINT)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + self.grace_s
        for mp in self.processes:
            if mp.popen is None:
                continue
            try:
                mp.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self._emit("launch", f"{mp.label} did not stop within {self.grace_s:.0f} s: SIGKILL")
        for mp in self.processes:
            if mp.popen is None:
                continue
            try:  # the whole group: also grandchildren a node may have started
                os.killpg(mp.popen.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            mp.popen.wait()
            if mp._reader is not None:
                mp._reader.join(timeout=2.0)
                mp._reader = None
        self._unlock_cells()

    def run(self, poll_s: float = 0.2) -> int:
        """Start, supervise until every process ended or a stop was requested; return exit code
        (CellLockError when a cell runs already)."""
        self.start()
        try:
            while not self._stopping.is_set():
                if not self.poll() or self.ended_by:
                    break
                self._stopping.wait(poll_s)
        finally:
            self.stop()
        if self.lifecycle_failures:
            return 1
        if self._stop_requested and not self.ended_by:
            return 0
        crashed = [mp for mp in self.processes if mp.exit_codes and mp.exit_codes[-1] != 0]
        return 1 if crashed else 0

    _stop_requested = False
    _brought_down = False
    #: label of the node whose crash (no restart left) ended the run; None while none did
    ended_by: str | None = None

    def request_stop(self) -> None:
        """Ask :meth:`run` to stop every process (safe from a signal handler)."""
        self._stop_requested = True
        self._stopping.set()


def main(argv: list[str] | None = None) -> int:
    """Start the nodes of one or more machine cells as separate processes."""
    ap = argparse.ArgumentParser(prog="thermal-comp launch", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Cell file format: see thermal_comp/cell/config.py or docs/architecture.md.")
    ap.add_argument("cells", nargs="+", metavar="CELL.yaml", help="machine-cell files")
    ap.add_argument("--run-dir", help="folder for parameter files and per-node logs (default: a temp dir)")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--restart", dest="restart", action="store_true", default=None,
                   help="restart crashed nodes (overrides the cell files)")
    g.add_argument("--no-restart", dest="restart", action="store_false", help="never restart crashed nodes")
    ap.add_argument("--grace", type=float, default=5.0, help="seconds to wait after SIGINT before SIGKILL")
    args = ap.parse_args(argv)
    try:
        cells = [load_cell(p) for p in args.cells]
        launcher = Launcher(cells, run_dir=args.run_dir, restart_override=args.restart, grace_s=args.grace)
        launcher.lock_cells()
    except (CellConfigError, CellLockError) as exc:
        print(f"thermal-comp launch: {exc}", file=sys.stderr)
        return 2

    def _on_signal(signum, frame):
        launcher.request_stop()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    print(f"[launch] run dir {launcher.run_dir}; cells: " +
          ", ".join(f"{c.namespace} (domain {c.domain_id if c.domain_id is not None else os.environ.get('ROS_DOMAIN_ID', 0)})"
                    for c in cells), flush=True)
    return launcher.run()


if __name__ == "__main__":
    sys.exit(main())
