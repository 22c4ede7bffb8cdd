"""Fault-table rows for "nothing hangs silently", "the recorder loses nothing" and
"one line for every bad file" (``thermal-comp bench faults``).

Each function runs the real commands or nodes as separate processes and returns table rows
(area, fault, injected, survived, data_lost, unsafe_writes, detail). The same cases are tests
in thermal_twin/test/twin/test_machine_sim_deadline.py, thermal_eval/test/reliability/
test_recorder_restart.py and thermal_comp/test/bags/test_bad_files.py.
"""
from __future__ import annotations

import math
import os
import pathlib
import signal
import subprocess
import sys
import time

from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError

from thermal_comp_common.bags.reader import BagReadError, read_bag
from thermal_comp_common.bags.repair import repair_bag
from thermal_comp_common.runtime.child_processes import stop
from thermal_comp_common.bags.msg_definitions import typestore

from thermal_eval.reliability.fault_rows import guarded


def _row(area, fault, survived, detail, data_lost=0) -> dict:
    return {"area": area, "fault": fault, "injected": 1, "survived": bool(survived),
            "data_lost": int(data_lost), "unsafe_writes": 0, "detail": detail[:90]}


def lockstep_absent_row(env: dict) -> dict:
    """A lock-step participant never joins: machine_sim names it and stops (exit 3)."""
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "thermal_twin.machine_sim_node", "--ros-args",
                        "-r", "__ns:=/bench_hang", "-p", "hours:=0.1",
                        "-p", "lockstep_participants:=['talc_model']", "-p", "lockstep_deadline_s:=3.0"],
                       env=env, capture_output=True, text=True, timeout=120)
    out = r.stdout + r.stderr
    named = "talc_model has not joined" in out and "t = 0 s" in out
    return _row("lock-step", "participant never joins", r.returncode == 3 and named,
                f"exit {r.returncode} after {time.monotonic() - t0:.1f} s, late participant named: {named}")


def recorder_lockstep_kill_row(out: pathlib.Path, env: dict) -> dict:
    """kill -9 of a lock-step recorder mid-run, restarted: every machine_sim instant is in
    bag + bag.2, and the killed bag is repaired for the standard rosbags reader.

    machine_sim waits for the restarted recorder (``participant_gone_s`` well above a restart at
    load: with the default 10 s a restart that slow is gone on without, and its instants are lost
    by design, which is what the participants test checks)."""
    ns, hours, step = "/bench_recorder", 4.0, 60.0   # 241 instants: the kill after 20 falls mid-run
    bag = out / "bag"
    rec = [sys.executable, "-m", "thermal_comp.bags.recorder_node", "--ros-args", "-r", f"__ns:={ns}",
           "-p", f"output:={bag}", "-p", "lockstep_participant:=true", "-p", "flush_period_s:=0.2"]
    out.mkdir(parents=True, exist_ok=True)
    sim_log = (out / "machine_sim.log").open("w")
    sim = subprocess.Popen([sys.executable, "-m", "thermal_twin.machine_sim_node", "--ros-args",
                            "-r", f"__ns:={ns}", "-p", f"hours:={hours}", "-p", f"step_s:={step}",
                            "-p", "lockstep_participants:=['bag_recorder']", "-p", "shutdown_when_done:=true",
                            "-p", "resend_after_s:=0.5", "-p", "lockstep_deadline_s:=150.0",
                            "-p", "participant_gone_s:=150.0"],
                           env=env, stdout=subprocess.DEVNULL, stderr=sim_log)
    logs = [out / "recorder_1.log", out / "recorder_2.log"]     # kept: a failed row says why
    handles = [sim_log] + [log.open("w") for log in logs]
    first = subprocess.Popen(rec, env=env, stdout=subprocess.DEVNULL, stderr=handles[1])
    second = None
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and _flushed_instants(bag, ns) < 20:
            time.sleep(0.2)
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
        second = subprocess.Popen(rec, env=env, stdout=subprocess.DEVNULL, stderr=handles[2])
        sim.wait(timeout=300)
    finally:
        for p in (first, second, sim):
            stop(p)
        for h in handles:
            h.close()
    repaired = repair_bag(bag)
    want = {int(round(k * step)) for k in range(int(hours * 3600 / step) + 1)}
    got: set[int] = set()
    readable, unreadable = 0, ""
    for b in (bag, out / "bag.2"):
        if b.is_dir():
            got |= {int(round(m.stamp_ns / 1e9)) for m in read_bag(b).messages
                    if m.topic == f"{ns}/machine_state"}
            try:
                with Reader(b) as r:
                    readable += sum(1 for _ in r.messages())
            except ReaderError as exc:     # a recorder that did not close its bag: say which, and its log
                log = logs[0 if b == bag else 1].read_text()[-400:]
                unreadable = f"; rosbags cannot read {b.name}: {exc} (recorder log tail: {log!r})"
    lost = len(want - got)
    closed = second is not None and second.returncode == 0     # the restarted recorder closed bag.2
    detail = (f"{len(got)}/{len(want)} instants in bag+bag.2; repaired, rosbags reads {readable} msgs"
              + ("" if closed else f"; restarted recorder exit {second and second.returncode}") + unreadable)
    row = _row("recorder", "kill -9 lock-step recorder, restarted", lost == 0 and readable > 0
               and repaired.damage is not None and not unreadable and closed, detail, data_lost=lost)
    if not row["survived"]:
        gone = [ln for ln in (out / "machine_sim.log").read_text().splitlines() if "goes on without" in ln]
        row["why"] = (detail + (f"; machine_sim: {gone[0][-200:]}" if gone else "")
                      + f" (recorder and machine_sim logs in {out})")     # the table's detail is cut at 90 chars
    return row


def _flushed_instants(bag: pathlib.Path, ns: str) -> int:
    try:
        return sum(1 for m in read_bag(bag).messages if m.topic == f"{ns}/machine_state")
    except (BagReadError, OSError):
        return 0


def bad_file_rows(out: pathlib.Path, env: dict) -> list[dict]:
    """Each bad input gives one line naming the file and the exit code its --help states."""
    out.mkdir(parents=True, exist_ok=True)
    cases = {
        "non-UTF-8 CSV": ("import-csv", "bad.csv", b"time_s,a_c\n0,\xff\xfe\n", 2),
        "binary CSV": ("import-csv", "binary.csv", bytes(range(256)), 2),
        "binary MCAP": ("play", "garbage.mcap", bytes(range(256)) * 4, 2),
        "non-UTF-8 bag metadata": ("view", "badbag/metadata.yaml", b"\xff\xfe\x00", 2),
    }
    rows = []
    for fault, (cmd, name, content, want) in cases.items():
        f = out / name
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(content)
        target = f.parent if name.endswith("metadata.yaml") else f
        argv = {"import-csv": [str(target), str(out / f"{f.stem}_out"), "--no-progress"],
                "play": [str(target), "--as-fast-as-possible"],
                "view": [str(target), "--rrd", str(out / "x.rrd"), "--no-progress"]}[cmd]
        r = subprocess.run([sys.executable, "-m", "thermal_comp.cli", cmd, *argv], env=env,
                           capture_output=True, text=True, timeout=120)
        lines = [x for x in r.stderr.splitlines() if x.strip()]
        ok = r.returncode == want and len(lines) == 1 and "Traceback" not in r.stderr
        rows.append(_row("bad file", f"{fault} ({cmd})", ok,
                         f"exit {r.returncode} (help: {want}): {lines[0] if lines else '(nothing)'}"))
    rows.append(_inf_reading_row(out, env))
    return rows


def _inf_reading_row(out: pathlib.Path, env: dict) -> dict:
    csv = out / "inf.csv"
    csv.write_text("time_s,a_c\n0,inf\n60,20.5\n")
    bag = out / "inf_bag"
    r = subprocess.run([sys.executable, "-m", "thermal_comp.cli", "import-csv", str(csv), str(bag),
                        "--no-progress", "--force"], env=env, capture_output=True, text=True, timeout=120)
    store = typestore()
    vals = [store.deserialize_cdr(m.data, m.type).temperatures_degc[0] for m in read_bag(bag).messages
            if m.topic == "/temperatures"] if r.returncode == 0 else []
    ok = len(vals) == 2 and math.isnan(vals[0]) and vals[1] == 20.5
    return _row("bad file", "failed reading (inf) imported", ok, f"failed reading stored as {float(vals[0]) if vals else None!r} (contract: NaN)")


def rows(out: pathlib.Path, domain_id: int) -> list[dict]:
    """Every row of this module (each case in its own folder under ``out``; a case that raises
    is one failed row with its reason)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    out.mkdir(parents=True, exist_ok=True)
    return [*guarded("lock-step", "participant never joins", lambda: lockstep_absent_row(env)),
            *guarded("recorder", "kill -9 lock-step recorder, restarted",
                     lambda: recorder_lockstep_kill_row(out / "recorder_lockstep", env)),
            *guarded("bad file", "(every bad-file row)", lambda: bad_file_rows(out / "bad_files", env))]
