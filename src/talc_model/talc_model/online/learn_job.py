"""``thermal-comp learn`` in a process of its own, never waited for: a snapshot of the cell's bag,
the command started in its own process group, polled, killed (the whole group) after a wall-clock
timeout, its failure reported with the last line it wrote. No rclpy.

Why a subprocess: ``learn`` belongs to thermal_eval, above talc_model in the package DAG, and takes
seconds to minutes; the model's lock-step must not wait for it, and a hang or a crash of it must not
touch the running model. The command is found through the ``thermal-comp`` command registry at run
time (``thermal-comp learn``), not imported.

Why a snapshot: the recorder appends to the bag while the cell runs. Its writer closes a chunk
every ``flush_period_s``; a byte prefix of the MCAP file is therefore a bag that ends early, which
``learn --allow-truncated`` reads up to its last complete chunk. The snapshot copies the bytes the
files hold at that moment, so the recorder is never paused and learn never sees a file change.
"""
from __future__ import annotations

import enum
import os
import pathlib
import shlex
import signal
import subprocess
import sys
from dataclasses import dataclass

#: bytes copied per read while snapshotting
_CHUNK = 1 << 20


def default_learn_command() -> list[str]:
    """``thermal-comp learn`` of this interpreter's environment."""
    return [str(pathlib.Path(sys.executable).with_name("thermal-comp")), "learn"]


def parse_command(text: str) -> list[str]:
    """A command line given as text (empty: :func:`default_learn_command`)."""
    return shlex.split(text) if text.strip() else default_learn_command()


def snapshot_bag(bag: pathlib.Path, dest: pathlib.Path) -> pathlib.Path:
    """Copy the MCAP files of the bag folder (or the one ``.mcap`` file) ``bag`` as they are now
    into the new folder ``dest``; ValueError (one line) when there is nothing to copy."""
    files = sorted(bag.glob("*.mcap")) if bag.is_dir() else [bag] if bag.suffix == ".mcap" else []
    if not files:
        raise ValueError(f"recording {str(bag)!r}: no .mcap file (yet)")
    dest.mkdir(parents=True)
    for f in files:
        size = f.stat().st_size
        with open(f, "rb") as src, open(dest / f.name, "wb") as out:
            left = size
            while left > 0:
                block = src.read(min(_CHUNK, left))
                if not block:
                    break
                out.write(block)
                left -= len(block)
    return dest


def learn_argv(command: list[str], recording: pathlib.Path, twin: str, out: pathlib.Path,
               train_h: float, current_prior: str = "", current_config: str = "") -> list[str]:
    """The learn command line on the snapshot ``recording`` (a bag that may end early); with
    ``current_prior`` (and ``current_config``) learn's adaptive test is against that prior, the
    one running now, instead of the type's."""
    argv = [*command, str(recording), "--twin", twin, "--out", str(out), "--train-h", f"{train_h:.3f}"]
    if current_prior:
        argv += ["--current-prior", current_prior]
        if current_config:
            argv += ["--current-config", current_config]
    return argv + ["--allow-truncated", "--quiet"]


class JobState(enum.Enum):
    RUNNING = "running"
    DONE = "done"            # exit 0: the report is to be read
    FAILED = "failed"        # exit != 0 or could not start
    TIMED_OUT = "timed out"  # killed after the timeout


@dataclass
class JobEnd:
    state: JobState
    reason: str              # one line ("" when done)
    wall_s: float


class LearnJob:
    """One learning subprocess (module docstring); ``poll(now_s)`` never blocks."""

    def __init__(self, argv: list[str], work: pathlib.Path, timeout_s: float, now_s: float):
        self.argv, self.work, self.timeout_s, self.started_s = argv, work, float(timeout_s), now_s
        self.stdout, self.stderr = work / "learn.out", work / "learn.err"
        with open(self.stdout, "wb") as out, open(self.stderr, "wb") as err:
            self.proc = subprocess.Popen(argv, stdout=out, stderr=err, stdin=subprocess.DEVNULL,
                                         start_new_session=True)

    def poll(self, now_s: float) -> JobEnd | None:
        """None while it runs; else how it ended (a job past its timeout is killed here)."""
        rc = self.proc.poll()
        wall = now_s - self.started_s
        if rc is None and wall <= self.timeout_s:
            return None
        if rc is None:
            self.kill()
            return JobEnd(JobState.TIMED_OUT, f"learn ran longer than {self.timeout_s:g} s: killed", wall)
        if rc != 0:
            return JobEnd(JobState.FAILED, f"learn exited with code {rc}: {self.last_error_line()}", wall)
        return JobEnd(JobState.DONE, "", wall)

    def kill(self) -> None:
        """Kill the job's whole process group and reap it."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(timeout=10.0)

    def last_error_line(self) -> str:
        """The last non-empty line the job wrote on stderr (what learn says when it refuses)."""
        try:
            lines = [ln.strip() for ln in self.stderr.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return "(no stderr)"
        return lines[-1][:300] if lines else "(nothing on stderr)"


def start_job(argv: list[str], work: pathlib.Path, timeout_s: float, now_s: float) -> LearnJob | JobEnd:
    """Start a job; a command that cannot start is a failed end at once (one line)."""
    try:
        return LearnJob(argv, work, timeout_s, now_s)
    except OSError as exc:
        return JobEnd(JobState.FAILED, f"could not start {argv[0]!r}: {exc.strerror or exc}", 0.0)
