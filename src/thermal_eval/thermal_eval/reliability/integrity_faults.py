"""Rows of ``thermal-comp bench faults`` for what is loaded or owned: a tampered prior (ARX
parameters x1000 with a fresh hash; one flipped byte), a tampered model state, a second launch
of a running cell and a full disk under the bag writer.

Each case runs the real loader, lock or writer in this process (the first owner of the cell
is a child process), on a small synthetic first-order plant, in seconds and without a ROS
graph. A refusal survives when it is one line naming what was refused; nothing here writes
to a CNC, so "unsafe writes" is 0 by construction.
"""
from __future__ import annotations

import copy
import errno
import math
import os
import pathlib
import shutil
import subprocess
import sys
from typing import Callable

import numpy as np

from talc_model.model_persistence import ModelStateError, load_model, save_model
from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import build_talc_prior, load_prior, save_prior
from talc_model.state_files import run_identity
from talc_model.talc.model import TalcModel
from thermal_comp.cell.cell_lock import CellLockError, acquire_cell_lock
from thermal_comp_common.bags import writer as bag_writer
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.writer import BagIOError, BagWriter, TopicInfo
from thermal_comp_common.recording_csv import Recording

from thermal_eval.reliability.fault_rows import guarded

#: the synthetic plant's model configuration (one component, one input)
CONFIG = {"component_names": ["E_X0C"], "angular_components": [], "input_names": ["amb"],
          "cp_length_h": 0.0, "post_cp_interval_h": 2.0, "na_max": 1, "nb_max": 2, "nb_max_final": 2}
STEP_S = 300.0


def _row(area: str, fault: str, survived: bool, detail: str, data_lost: int = 0) -> dict:
    return {"area": area, "fault": fault, "injected": 1, "survived": bool(survived),
            "data_lost": int(data_lost), "unsafe_writes": 0, "detail": detail[:90]}


def _plant(seed: int, hours: float = 48.0) -> Recording:
    """E_X0C: a 3 h first-order lag of 3 um/K times the ambient's deviation from 20 C."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, STEP_S)
    amb = 20.0 + sum(rng.uniform(0.5, 2.0) * np.sin(2 * np.pi * t / (rng.uniform(4, 30) * 3600) + rng.uniform(0, 6))
                     for _ in range(3))
    amb -= amb[0] - 20.0
    a = math.exp(-STEP_S / (3 * 3600.0))
    e = np.zeros_like(t)
    for k in range(1, t.size):
        e[k] = a * e[k - 1] + (1 - a) * 3.0 * (amb[k - 1] - 20.0)
    return Recording(t, {"amb_c": amb, "E_X0C": e}, source=f"synthetic seed {seed}")


def _one_line(fn: Callable[[], object], refusal: type[Exception]) -> str | None:
    """The refusal's message if ``fn`` raises ``refusal`` in one line, else None."""
    try:
        fn()
    except refusal as exc:
        return None if "\n" in str(exc) else str(exc)
    return None


def prior_rows(out: pathlib.Path) -> list[dict]:
    """A prior whose ARX parameters were scaled x1000 (and re-hashed, as a careful forger would),
    and a prior file with one byte changed: both refused in one line before use."""
    prior = build_talc_prior([_plant(1), _plant(2), _plant(3)], CONFIG, machine="synthetic", nb_max=2,
                             sources=["p1", "p2", "p3"])
    scaled = copy.deepcopy(prior)
    for m in scaled["talc_state"]["models"].values():
        m["theta"] = [v * 1000.0 for v in m["theta"]]
    path = save_prior(out / "x1000.json", scaled)
    line = _one_line(lambda: model_from_prior("talc", CONFIG, load_prior(path)), PriorError)
    rows = [_row("integrity", "prior: ARX x1000, hash re-computed", line is not None,
                 f"refused: {line.split(': ', 1)[-1]}" if line else "used")]
    path = save_prior(out / "flipped.json", prior)
    data = bytearray(path.read_bytes())
    i = data.index(b'"theta": [') + len(b'"theta": [') + 3          # a digit of the first parameter
    data[i] = ord("1") if data[i] != ord("1") else ord("2")
    path.write_bytes(bytes(data))
    line = _one_line(lambda: load_prior(path), PriorError)
    rows.append(_row("integrity", "prior: one byte flipped", line is not None and "sha256" in line,
                     f"refused: {line.split(': ', 1)[-1]}" if line else "loaded"))
    return rows


def state_row(out: pathlib.Path) -> dict:
    """A saved model state edited by hand (refused by its hash) and one of other inputs than
    the run (refused by its identity), each in one line."""
    model = TalcModel(CONFIG)
    rec = _plant(5, hours=6.0)
    for k, t in enumerate(rec.time_s):
        model.update_inputs(float(t), {"amb": float(rec.columns["amb_c"][k])}, {})
    path = out / "state.json"
    save_model(path, model)
    text = path.read_text()
    path.write_text(text.replace('"input_names":["amb"]', '"input_names":["ambient"]', 1))
    edited = _one_line(lambda: load_model(path, "talc"), ModelStateError)
    save_model(path, model)
    other = {**CONFIG, "input_names": ["ambient", "cutting_oil"]}
    relabelled = _one_line(lambda: load_model(path, "talc", expected=run_identity(other, TalcModel(other))),
                           ModelStateError)
    ok = edited is not None and "sha256" in edited and relabelled is not None
    return _row("integrity", "model state: edited / other inputs", ok,
                f"both refused: {relabelled.split(': ', 1)[-1]}" if ok
                else f"edited: {edited or 'resumed'}; other inputs: {relabelled or 'resumed'}")


#: the first owner of the cell: holds its lock, says so, and waits for its stdin to close
_OWNER = ("import sys; from thermal_comp.cell.cell_lock import acquire_cell_lock; "
          "lock = acquire_cell_lock(int(sys.argv[1]), sys.argv[2], __import__('pathlib').Path(sys.argv[3])); "
          "print('held', flush=True); sys.stdin.read()")


def second_launch_row(out: pathlib.Path) -> dict:
    """A second owner of a running cell (same domain and namespace) is refused naming the first
    one's pid; once the first is gone (kill -9), its stale lock is taken over with a warning."""
    lock_dir, domain, ns = out / "locks", 7, "/bench_cell"
    first = subprocess.Popen([sys.executable, "-c", _OWNER, str(domain), ns, str(lock_dir)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        held = first.stdout.readline().strip() == "held"
        line = _one_line(lambda: acquire_cell_lock(domain, ns, lock_dir).release(), CellLockError)
    finally:
        first.kill()
        first.wait(timeout=30)
    named = line is not None and f"pid {first.pid}" in line
    lock = acquire_cell_lock(domain, ns, lock_dir)
    taken_over = str(first.pid) in lock.warning
    lock.release()
    return _row("cell", "second launch of a running cell", held and named and taken_over,
                f"refused naming pid {first.pid}; stale lock taken over with a warning" if held and named
                and taken_over else f"second launch: {line or 'not refused'}; takeover: {lock.warning!r}")


class _SmallDisk:
    """Files the bag writer opens live on a disk of ``capacity`` bytes under ``root``: a write
    beyond it writes what fits, then raises ENOSPC, as a full file system does."""

    def __init__(self, root: pathlib.Path, capacity: int):
        self.root, self.capacity = root, capacity

    def used(self) -> int:
        return sum(p.stat().st_size for p in self.root.rglob("*") if p.is_file())

    def open(self, path, mode="r", *args, **kw):
        binary = "b" in mode
        f = open(path, mode, *args, **({"buffering": 0} if binary else {}), **kw)
        return _FillingFile(f, self, binary)


class _FillingFile:
    def __init__(self, f, disk: _SmallDisk, binary: bool):
        self._f, self._disk, self._binary = f, disk, binary

    def write(self, data):
        self._f.flush()
        free = self._disk.capacity - self._disk.used()
        size = len(data if self._binary else data.encode())
        if size > free:
            if self._binary and free > 0:
                self._f.write(bytes(data)[:free])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()


def full_disk_row(out: pathlib.Path, capacity: int = 200_000) -> dict:
    """The bag writer fills a disk of ``capacity`` bytes (flushing every 5 messages, as the
    recorder does): it closes the bag readable, marked incomplete, in one line, and every
    message flushed before the failure is in it intact."""
    topic = TopicInfo("/bench/temperatures", "thermal_comp_msgs/msg/TemperatureArray")
    root = out / "disk"
    shutil.rmtree(root, ignore_errors=True)      # the disk of a previous run
    root.mkdir(parents=True)

    def message(t_s: int) -> bytes:      # CDR: a leading stamp (sec, nanosec), then filler
        return b"\x00\x01\x00\x00" + t_s.to_bytes(4, "little") + bytes(4) + bytes((t_s + k) % 251 for k in range(400))
    bag_writer.open = _SmallDisk(root, capacity).open      # the writer's files, on the small disk
    flushed, line = 0, None
    try:
        w = BagWriter(root / "bag", [topic], chunk_bytes=4096, compression="none")
        for t in range(1, 100_000):
            w.write(topic.name, t * 10**9, message(t))
            if t % 5 == 0:
                w.flush()
                flushed = t
    except BagIOError as exc:
        line = None if "\n" in str(exc) else str(exc)
    finally:
        del bag_writer.open
    contents = read_bag(root / "bag")
    kept = {m.stamp_ns // 10**9 for m in contents.messages if m.data == message(m.stamp_ns // 10**9)}
    lost = len(set(range(1, flushed + 1)) - kept)      # flushed before the failure, not in the bag intact
    ok = (line is not None and "ENOSPC" in line and "incomplete" in (contents.damage or "")
          and lost == 0 and flushed > 0)
    return _row("recorder", "disk full while recording (ENOSPC)", ok,
                f"{len(kept)} msgs readable ({flushed} flushed), marked incomplete: "
                f"{'incomplete' in (contents.damage or '')}; one line: {line is not None}", data_lost=lost)


def rows(out: pathlib.Path) -> list[dict]:
    """Every row of this module (a case that raises is one failed row with its reason)."""
    out.mkdir(parents=True, exist_ok=True)
    return [*guarded("integrity", "(every prior row)", lambda: prior_rows(out / "prior")),
            *guarded("integrity", "model state: edited / other inputs", lambda: state_row(out / "state")),
            *guarded("cell", "second launch of a running cell", lambda: second_launch_row(out / "cell")),
            *guarded("recorder", "disk full while recording (ENOSPC)", lambda: full_disk_row(out / "disk"))]
