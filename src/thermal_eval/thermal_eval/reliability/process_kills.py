"""Process kills of a running graph under the launcher: ``kill -9`` of a node's whole process
group at a simulated instant (:class:`KillPlan`), then the launcher's restart policy takes
over; :func:`run_graph_faults` runs the demo graph with such a plan and counts data lost and
unsafe writes; :func:`run_recorder_kill` kills the bag recorder mid-chunk.
"""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from rclpy.serialization import deserialize_message

from cnc_bridge.audit_log import read_audit_log
from thermal_comp.demo.cell import MACHINES, DemoConfig
from thermal_comp.demo.cell import DEFAULT_PRIOR
from thermal_comp.demo.run import resolve_prior
from thermal_comp.demo.graph import run_graph
from thermal_comp.demo.series import read_series
from thermal_comp.demo.summary import compensation_in_effect, summarise
from thermal_comp_common import metrics
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_msgs.msg import ModelStatus
from thermal_eval.reliability.offset_safety_checks import offset_violations

@dataclass
class Kill:
    """``kill -9`` of node ``node`` once simulated time reaches ``at_sim_s``."""

    node: str
    at_sim_s: float
    done_wall: float | None = None
    #: the simulated time the supervisor saw when it killed (the plan's instant or a little later)
    done_sim_s: float | None = None
    pid: int | None = None
    restarted_pid: int | None = None


@dataclass
class KillPlan:
    """Kills to perform while a graph runs; call :meth:`poll` from the supervision loop."""

    kills: list[Kill] = field(default_factory=list)

    def poll(self, launcher, sim_s: float) -> None:
        by_name = {mp.node.name: mp for mp in launcher.processes}
        for k in self.kills:
            mp = by_name.get(k.node)
            if mp is None:
                raise ValueError(f"KillPlan: no node named {k.node!r} (have {sorted(by_name)})")
            if k.done_wall is None and sim_s >= k.at_sim_s and mp.running():
                k.pid = mp.pid
                try:
                    os.killpg(mp.pid, signal.SIGKILL)   # the node and anything it started
                except ProcessLookupError:
                    continue
                k.done_wall = time.monotonic()
                k.done_sim_s = float(sim_s)
            elif k.done_wall is not None and k.restarted_pid is None and mp.running() and mp.pid != k.pid:
                k.restarted_pid = mp.pid

    @property
    def all_done(self) -> bool:
        return all(k.done_wall is not None for k in self.kills)


#: simulated s per wall s while kills are planned: a 300-s instant takes 0.3 wall s, about one
#: supervision poll, so a kill lands at the instant planned or the next
KILL_PACE = 1000.0

#: The bridge's envelope in the demo cell (cnc_bridge_node defaults) for the audit-log check;
#: a machine of demo_cell.MACHINES may set its own ``abs_limit_um`` (see :func:`demo_envelope`).
DEMO_ENVELOPE = {"max_rate_um_per_s": 0.5, "abs_limit_um": 30.0, "max_step_s": 600.0}


def demo_envelope(machine: str) -> dict[str, float]:
    """The envelope the demo cell gives the bridge of ``machine``."""
    return {**DEMO_ENVELOPE, "abs_limit_um": float(MACHINES[machine].get("abs_limit_um",
                                                                          DEMO_ENVELOPE["abs_limit_um"]))}


def _audit_check(audit_log: pathlib.Path, truth: set[int], first_pred: int, envelope: Mapping[str, float]):
    """The bridge's audit log: its rows, the writes that broke the demo envelope, and the
    instants (s) after the first prediction that no audit row covers."""
    rows = read_audit_log(audit_log)
    times = sorted({float(r["time_s"]) for r in rows})
    index = {t: i for i, t in enumerate(times)}
    applied: dict[str, np.ndarray] = {}
    for r in rows:
        a = applied.setdefault(r["axis"], np.full(len(times), np.nan))
        a[index[float(r["time_s"])]] = float(r["applied_um"]) if r["applied_um"] else np.nan
    violations = offset_violations(times, applied, **envelope)
    audited = {round(t, 3) for t in times}
    missing = sorted(t / 1e9 for t in truth if t >= first_pred and round(t / 1e9, 3) not in audited)
    return rows, violations, missing


def run_graph_faults(out_dir, hours: float, kills: Sequence[Kill] = (), seed: int = 0,
                     wall_timeout_s: float = 600.0, progress: bool = False,
                     p99_until_h: float | None = None, prior: str | None = DEFAULT_PRIOR,
                     real_time_factor: float | None = None) -> dict:
    """The demo graph (nmv5000, talc-178h-dry shortened to ``hours``, OPC UA to the CNC
    emulator) under the launcher with restarts enabled, ``kills`` performed mid-run.
    ``prior``: as the demo's (default: the machine type's prior; None: the thesis's start,
    whose model leaves calibration only after about 5 h). ``real_time_factor``: machine_sim's
    lock-step ceiling; None = KILL_PACE with kills (the launcher polls at about 4 Hz, so a kill
    lands within an instant or two of ``at_sim_s``; unpaced, 6 h can pass between two polls),
    else as fast as possible.

    Returns the demo summary plus what the faults did: restarts per node, whether the model
    resumed from its saved state (and never went back to calibration), instants that lack
    temperatures / predictions / offsets in the bag (data lost), bag damage, and audit-log
    writes that broke the bridge's envelope (unsafe writes).
    """
    out = pathlib.Path(out_dir)
    cfg = DemoConfig(out_dir=out, hours=hours, seed=seed, view="none", progress=progress, cnc="opcua",
                     wall_timeout_s=wall_timeout_s,
                     restart={"enabled": True, "max_restarts": 3, "backoff_s": 0.5})
    cfg.scenario = "talc-178h-dry"
    cfg.prior = prior
    cfg.real_time_factor = (KILL_PACE if kills else 0.0) if real_time_factor is None else real_time_factor
    resolve_prior(cfg)
    plan = KillPlan([Kill(k.node, k.at_sim_s) for k in kills])
    record = run_graph(cfg, on_poll=plan.poll)
    contents = read_bag(out / "bag")
    stamps: dict[str, set[int]] = {}
    probing, phases = [], []
    for m in contents.messages:
        name = m.topic.split("/", 2)[-1]
        stamps.setdefault(name, set()).add(m.stamp_ns)
        if name == "model_status":
            st = deserialize_message(m.data, ModelStatus)
            probing.append(int(st.probing_cycles))
            phases.append(int(st.phase))
    truth = stamps.get("errors/ground_truth", set())
    first_pred = min(stamps.get("errors/predicted", {0}))
    missing = {topic: sorted({t for t in truth if t >= first_pred} - stamps.get(topic, set()))
               for topic in ("temperatures", "errors/predicted", "offsets")}
    lost = {topic: len(v) for topic, v in missing.items()}
    left_calibration = next((i for i, p in enumerate(phases) if p != ModelStatus.PHASE_CALIBRATION), None)
    status_times = [m.stamp_ns for m in contents.messages if m.topic.endswith("model_status")]
    back_to_calibration = left_calibration is not None and any(
        p == ModelStatus.PHASE_CALIBRATION for p in phases[left_calibration:])
    counter_regressions = sum(1 for a, b in zip(probing, probing[1:]) if b < a)
    log_text = (out / "logs" / "nodes.log").read_text(errors="replace")
    rows, violations, audit_missing = _audit_check(out / "cnc_audit.log", truth, first_pred,
                                                 demo_envelope(cfg.machine))
    series = read_series(out / "bag")
    summary = summarise(series, cfg, record)
    p99_until = None
    if p99_until_h is not None:   # compensated P99 over the instants before p99_until_h only
        comp = compensation_in_effect(series)
        keep = series.t_true < p99_until_h * 3600.0
        p99_until = {c: round(metrics.p99(series.true[c][keep], comp[c][keep]), 3) for c in series.components}
    return {
        "summary": summary,
        "kills": [{"node": k.node, "at_sim_h": round(k.at_sim_s / 3600.0, 2),
                   "killed_at_sim_h": None if k.done_sim_s is None else round(k.done_sim_s / 3600.0, 2),
                   "killed": k.done_wall is not None,
                   "restarted": k.restarted_pid is not None} for k in plan.kills],
        "restarts": dict(record.restarts),
        "model_resumed": log_text.count("model: resumed from"),
        "twin_resumed": log_text.count("resumed from") - log_text.count("model: resumed from"),
        "calibration_ended_h": (round(status_times[left_calibration] / 3.6e12, 2)
                                if left_calibration is not None else None),
        "back_to_calibration": back_to_calibration,
        "probing_counter_regressions": counter_regressions,
        "instants": len(truth),
        "lost": lost,
        "missing_at_h": {k: [round(t / 3.6e12, 3) for t in v] for k, v in missing.items() if v},
        "bag_damage": contents.damage,
        "audit_writes": len(rows),
        "audit_missing_at_h": [round(t / 3600.0, 3) for t in audit_missing],
        "unsafe_writes": [str(v) for v in violations],
        "wall_s": round(record.wall_s, 1),
        "p99_compensated_until": p99_until,
    }


def compare_p99(undisturbed: Mapping, disturbed: Mapping) -> dict[str, float]:
    """Per component: compensated P99 of the disturbed run minus the undisturbed one."""
    a, b = undisturbed["errors"], disturbed["errors"]
    return {c: round(b[c]["p99_compensated"] - a[c]["p99_compensated"], 3) for c in a if c in b}


def run_recorder_kill(out_dir, domain_id: int, min_bytes: int = 20000, wall_timeout_s: float = 60.0) -> dict:
    """``kill -9`` of the bag recorder while a free-running twin publishes, then read the bag.

    The recorder closes a chunk every 0.2 s (wall); once its MCAP file holds ``min_bytes``
    it is killed. Returns the messages readable, the damage :func:`read_bag` reports, and
    what a restart of the recorder onto the same output does (exit code, first error line).
    """
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")
    ns = ["--ros-args", "-r", "__ns:=/rec_kill"]
    sim = subprocess.Popen([sys.executable, "-m", "thermal_twin.machine_sim_node", *ns, "-p", "hours:=200.0",
                            "-p", "real_time_factor:=6000.0", "-p", "step_s:=300.0"],
                           env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    rec_argv = [sys.executable, "-m", "thermal_comp.bags.recorder_node", *ns, "-p", f"output:={bag}",
                "-p", "flush_period_s:=0.2"]
    rec = subprocess.Popen(rec_argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           start_new_session=True)
    try:
        deadline = time.monotonic() + wall_timeout_s
        mcap = None
        while time.monotonic() < deadline:
            files = list(bag.glob("*.mcap")) if bag.is_dir() else []
            if files and files[0].stat().st_size >= min_bytes:
                mcap = files[0]
                break
            if rec.poll() is not None:
                raise RuntimeError(f"recorder exited with {rec.returncode}: {rec.stdout.read()}")
            time.sleep(0.05)
        if mcap is None:
            raise RuntimeError(f"recorder wrote fewer than {min_bytes} bytes in {wall_timeout_s:.0f} s")
        os.killpg(rec.pid, signal.SIGKILL)
        rec.wait()
        size_at_kill = mcap.stat().st_size
        contents = read_bag(bag)
        # the launcher's restart: the recorder keeps the crashed bag and continues in bag.2
        rec = subprocess.Popen(rec_argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               start_new_session=True)
        cont = out / "bag.2"
        deadline = time.monotonic() + wall_timeout_s
        while time.monotonic() < deadline:
            files = list(cont.glob("*.mcap")) if cont.is_dir() else []
            if files and files[0].stat().st_size >= min_bytes // 4:
                break
            if rec.poll() is not None:
                break
            time.sleep(0.05)
        if rec.poll() is None:
            os.killpg(rec.pid, signal.SIGINT)
            rec.wait(timeout=wall_timeout_s)
        restart_out = rec.stdout.read() if rec.stdout else ""
        continued = read_bag(cont) if (cont / "metadata.yaml").is_file() else None
        return {"bytes_at_kill": size_at_kill, "messages_readable": len(contents.messages),
                "topics": sorted({m.topic for m in contents.messages}), "damage": contents.damage,
                "restart_exit_code": rec.returncode, "restart_output": restart_out,
                "restart_messages": len(continued.messages) if continued else 0,
                "crashed_bag_unchanged": mcap.stat().st_size == size_at_kill}
    finally:
        for p in (sim, rec):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
