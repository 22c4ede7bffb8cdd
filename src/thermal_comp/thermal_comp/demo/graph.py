"""Run the demo graph: the CNC emulator, the launcher with every node of the demo cell, and a
monitor, supervised until the twin's scenario ends; ``bench graph`` measures that run.

``THERMAL_COMP_OBSERVER_NICE`` (0-19, default 0: every process alike) starts the observers
(recorder, viewer, probe cycle) at that niceness, below the control path sensors -> model ->
bridge -> CNC, as a real cell would, so that they do not take a core from it while an instant's
offsets are on their way. Not the default: the recorder and the probe cycle also hold the
lock-step, and on a loaded machine the graph ran 1.5-2.2 times slower (docs/cnc_bridge.md)."""
from __future__ import annotations

import os
import pathlib
import shutil
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import psutil

from cnc_bridge.update_profile import read_profile
from thermal_comp.cell.config import parse_cell
from thermal_comp.demo.cell import AUDIT, LEARN_DIR, MACHINES, DemoConfig, DemoError, build_cell, scenario_hours
from thermal_comp.demo.monitor import DemoMonitor
from thermal_comp.demo.graph_profile import ack_breakdown, instant_events, latency_breakdown, stage_breakdown
from thermal_comp.cell.cell_lock import CellLockError
from thermal_comp.cell.launcher import NICE_ENV, Launcher
from thermal_comp_common.runtime import node_runtime as rt
from thermal_comp_common.plain_output import progress
from thermal_comp_common.runtime.domain_ids import claim_domain_id


@dataclass
class RunRecord:
    """What the demo's monitor saw while the graph ran (wall-time figures for the benchmark)."""

    sim_end_s: float = 0.0
    wall_s: float = 0.0
    latencies_s: list[float] = field(default_factory=list)
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    #: CPU seconds (user + system) each node's process tree used, last seen (restarts add up)
    cpu_s: dict[str, float] = field(default_factory=dict)
    node_exit_codes: dict[str, list[int]] = field(default_factory=dict)
    restarts: dict[str, int] = field(default_factory=dict)
    #: niceness each process ran at (observers lowered; the rest 0)
    niceness: dict[str, int] = field(default_factory=dict)
    #: where an instant's wall time went (thermal_comp.demo.graph_profile), per stage and per participant
    stages: dict[str, dict[str, float]] = field(default_factory=dict)
    acks: dict[str, dict[str, float]] = field(default_factory=dict)
    #: the temperature -> offsets latency split into its parts (with the bridge's own timing)
    latency_parts: dict[str, dict[str, float]] = field(default_factory=dict)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, proc: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise DemoError(f"CNC emulator exited with code {proc.returncode} before listening on port {port}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise DemoError(f"CNC emulator not listening on 127.0.0.1:{port} after {timeout_s:.0f} s")


def _children_map() -> dict[int, list[int]]:
    """Parent pid -> child pids of every process on the host (one pass over /proc)."""
    children: dict[int, list[int]] = {}
    for q in psutil.process_iter(["ppid"]):
        children.setdefault(q.info["ppid"], []).append(q.pid)
    return children


def _usage_tree(pid: int, children: dict[int, list[int]] | None = None) -> tuple[float, float]:
    """(resident MiB, CPU s) of a process and its children (``children``: a :func:`_children_map`
    shared by several calls; psutil's own walk reads all of /proc once per process)."""
    children = _children_map() if children is None else children
    mem = cpu = 0.0
    tree, seen = [pid], 0
    while seen < len(tree):
        tree += children.get(tree[seen], [])
        seen += 1
    for q_pid in tree:
        try:
            q = psutil.Process(q_pid)
            with q.oneshot():
                mem += q.memory_info().rss
                t = q.cpu_times()
                cpu += t.user + t.system
        except psutil.Error:
            continue
    return mem / 2**20, cpu


def _fresh_out_dir(cfg: DemoConfig) -> pathlib.Path:
    """The output folder without the files of a previous run."""
    out = cfg.out_dir.resolve()
    for folder in ("bag", LEARN_DIR):
        if (out / folder).exists():
            shutil.rmtree(out / folder)
    for stale in ("model_state.json", "cnc_audit.log", "twin_state.pkl", BRIDGE_PROFILE,
                  PUBLICATION_TIMES, AUDIT, "model_state.json.adopted.yaml"):
        (out / stale).unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _start_emulator(cfg: DemoConfig, log_dir: pathlib.Path) -> tuple[subprocess.Popen, str]:
    """The OPC UA CNC emulator as a separate process, listening; (process, endpoint)."""
    port = _free_port()
    endpoint = f"opc.tcp://127.0.0.1:{port}/thermal-comp/cnc"
    emu_log = open(log_dir / "cnc_emulator.log", "w")
    axes = MACHINES[cfg.machine].get("offset_axes")
    emulator = subprocess.Popen([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--port", str(port)]
                                + (["--compensation-axes", ",".join(axes)] if axes else []),
                                stdout=emu_log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        _wait_port(port, emulator, 60.0)
    except DemoError:
        _stop_emulator(emulator)
        raise
    return emulator, endpoint


def _stop_emulator(emulator: subprocess.Popen) -> None:
    emulator.terminate()
    try:
        emulator.wait(timeout=10)
    except subprocess.TimeoutExpired:
        emulator.kill()


#: the demo cell's observers: off the temperature -> offsets path, started at a lower priority
OBSERVERS = ("recorder", "viewer", "probe_cycle")
#: environment variable: the observers' niceness (0-19; 0: every process alike)
OBSERVER_NICE_ENV = "THERMAL_COMP_OBSERVER_NICE"


def observer_niceness() -> int:
    """The observers' niceness from :data:`OBSERVER_NICE_ENV` (default 0)."""
    text = os.environ.get(OBSERVER_NICE_ENV, "0").strip()
    if not text.isdigit() or int(text) > 19:
        raise DemoError(f"{OBSERVER_NICE_ENV}={text!r} is not a niceness 0-19")
    return int(text)


def _lower_observers(doc: dict, nice: int) -> None:
    """Start the observers of the cell document ``doc`` at niceness ``nice`` (launcher: NICE_ENV)."""
    if nice:
        for node in doc["nodes"]:
            if node["name"] in OBSERVERS:
                node.setdefault("env", {})[NICE_ENV] = str(nice)


#: the bridge's timing of each prediction (cnc_bridge.update_profile), in the output folder
BRIDGE_PROFILE = "bridge_profile.csv"


def run_graph(cfg: DemoConfig, on_poll=None, profile_bridge: bool = False) -> RunRecord:
    """Run the demo graph until the twin's scenario ends; return what was observed.

    ``on_poll(launcher, sim_s)``, if given, is called on every supervision poll (about 4 Hz)
    with the launcher and the simulated time seen so far (fault injection uses it).
    ``profile_bridge``: the bridge times each prediction (``profile_path``) and the record
    gets the latency's parts (``latency_parts``)."""
    out = _fresh_out_dir(cfg)
    total_h = scenario_hours(cfg.machine, cfg.scenario, cfg.hours)
    domain_id = claim_domain_id()
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_LOG_DIR", str(out / "logs" / "ros"))
    # the nodes' executor: rclpy's EventsExecutor takes about a third of the CPU per message
    # of the SingleThreadedExecutor, which on 2 cores sets the graph's speed (bench graph)
    os.environ.setdefault(rt.EXECUTOR_ENV, "events")
    live_view = cfg.view == "live" or (cfg.view == "auto" and bool(os.environ.get("DISPLAY")))
    log_dir = out / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    emulator, endpoint = _start_emulator(cfg, log_dir) if cfg.cnc == "opcua" else (None, None)

    doc = build_cell(cfg, domain_id, endpoint, live_view)
    nice = observer_niceness()
    _lower_observers(doc, nice)
    if profile_bridge:
        bridge = next(n for n in doc["nodes"] if n["name"] == "bridge")
        bridge["parameters"]["profile_path"] = str(out / BRIDGE_PROFILE)
    cell = parse_cell(doc, source="demo cell")
    print(f"demo graph: namespace /{cell.cell}, ROS_DOMAIN_ID {domain_id} (inspect with: thermal-comp topics "
          f"--domain-id {domain_id}); node logs: {log_dir / 'nodes.log'}", flush=True)
    node_log = open(log_dir / "nodes.log", "w")
    launcher = Launcher([cell], run_dir=log_dir / "run", output=node_log, grace_s=10.0)
    record = RunRecord()
    monitor = None
    monitor_arrivals = None
    bar = None
    t_start = time.perf_counter()
    try:
        try:
            launcher.start()
        except CellLockError as exc:
            raise DemoError(str(exc)) from None
        monitor = DemoMonitor("/" + cell.cell)
        if cfg.progress:
            bar = progress(round(total_h, 2), f"{cfg.machine} {cfg.scenario}", "sim h", decimals=1)
        _supervise(cfg, launcher, monitor, bar, record, total_h, log_dir, on_poll)
        record.wall_s = time.perf_counter() - t_start
        record.sim_end_s = monitor.sim_s
    finally:
        if bar is not None:
            bar.close()
        launcher.request_stop()
        launcher.stop()
        if monitor is not None:
            record.latencies_s = list(monitor.latencies)
            participants = _participants(cell)
            record.stages = stage_breakdown(instant_events(monitor.arrivals, monitor.acks, participants))
            record.acks = ack_breakdown(monitor.arrivals, monitor.acks, participants)
            monitor_arrivals = monitor.arrivals
            monitor.close()
        if monitor_arrivals is not None and profile_bridge:
            _write_publication_times(out / PUBLICATION_TIMES, monitor_arrivals)
        if monitor_arrivals is not None and (out / BRIDGE_PROFILE).exists():
            record.latency_parts = latency_breakdown(monitor_arrivals, read_profile(out / BRIDGE_PROFILE))
        if emulator is not None:
            record.cpu_s["cnc_emulator"] = _usage_tree(emulator.pid)[1]
            _stop_emulator(emulator)
        node_log.close()
    record.node_exit_codes = {mp.node.name: mp.exit_codes for mp in launcher.processes}
    record.restarts = {mp.node.name: mp.restarts for mp in launcher.processes}
    record.niceness = {**{mp.node.name: mp.nice for mp in launcher.processes},
                       **({"cnc_emulator": 0} if emulator is not None else {})}
    return record


#: every instant's publication times as the monitor saw them (topic, stamp_ns, wall s), for
#: lining the latency's tail up with what else ran then (e.g. a scheduler trace)
PUBLICATION_TIMES = "publication_times.csv"


def _write_publication_times(path: pathlib.Path, arrivals: dict[tuple[str, int], float]) -> None:
    with open(path, "w") as f:
        f.write("topic,stamp_ns,published_wall_s\n")
        for (topic, stamp), t in sorted(arrivals.items(), key=lambda kv: kv[1]):
            f.write(f"{topic},{stamp},{t:.6f}\n")


def _participants(cell) -> list[str]:
    """The lock-step participants machine_sim waits for in ``cell``."""
    sim = next(n for n in cell.nodes if n.name == "machine_sim")
    return [n for n in sim.parameters.get("lockstep_participants", []) if n]


#: how often the supervision samples each node's memory and CPU time (s)
USAGE_PERIOD_S = 1.0


def _supervise(cfg: DemoConfig, launcher: Launcher, monitor: DemoMonitor, bar, record: RunRecord,
               total_h: float, log_dir: pathlib.Path, on_poll) -> None:
    """Poll the launcher (about 4 Hz) until machine_sim ends its scenario; raise DemoError if it
    fails, a node crashes for good, or the wall-time limit passes."""
    sim_proc = next(mp for mp in launcher.processes if mp.node.name == "machine_sim")
    cpu_by_pid: dict[str, dict[int, float]] = {}
    deadline = time.monotonic() + cfg.wall_timeout_s
    next_usage = 0.0
    while True:
        launcher.poll()
        # the usage sample is this process's largest work besides the monitor (about 10 ms of
        # CPU for eight nodes on a busy host), taken on a core the graph needs: once a second
        sample = time.monotonic() >= next_usage
        children = _children_map() if sample else {}
        next_usage = time.monotonic() + USAGE_PERIOD_S if sample else next_usage
        for mp in launcher.processes if sample else ():
            if mp.pid:
                mem, cpu = _usage_tree(mp.pid, children)
                record.peak_rss_mb[mp.node.name] = max(record.peak_rss_mb.get(mp.node.name, 0.0), mem)
                cpu_by_pid.setdefault(mp.node.name, {})[mp.pid] = max(
                    cpu, cpu_by_pid.get(mp.node.name, {}).get(mp.pid, 0.0))
                record.cpu_s[mp.node.name] = sum(cpu_by_pid[mp.node.name].values())
        if on_poll is not None:
            on_poll(launcher, monitor.sim_s)
        if bar is not None:
            bar.to(monitor.sim_s / 3600.0)
        if sim_proc.popen.poll() is not None:
            launcher.poll()    # handle the exit first: a crash may be due for a restart
        if sim_proc.popen.poll() is not None and sim_proc.next_start is None:
            if sim_proc.popen.returncode != 0:
                raise DemoError(f"machine_sim exited with code {sim_proc.popen.returncode}; "
                                f"see {log_dir / 'nodes.log'}")
            return
        crashed = [mp.label for mp in launcher.processes if mp.gave_up or
                   (mp.popen and mp.popen.poll() not in (None, 0) and not mp.node.restart.enabled)]
        if crashed:
            raise DemoError(f"node(s) {crashed} crashed; see {log_dir / 'nodes.log'}")
        if time.monotonic() > deadline:
            raise DemoError(f"the graph did not finish within {cfg.wall_timeout_s:.0f} s wall time "
                            f"(reached {monitor.sim_s / 3600:.1f} of {total_h:.1f} sim h)")
        time.sleep(0.25)


def bench_graph(args) -> dict[str, Any]:
    """Whole-graph closed-loop speed (x real time), temperature->offsets latency, peak memory per node."""
    hours = 12.0 if getattr(args, "quick", False) else None
    out = pathlib.Path(getattr(args, "out_dir", "bench_out")) / "graph"
    cfg = DemoConfig(out_dir=out, hours=hours, view="rrd", progress=True)
    cfg.scenario = MACHINES[cfg.machine]["scenario"]
    load_before = os.getloadavg()[0]
    record = run_graph(cfg, profile_bridge=True)
    load_after = os.getloadavg()[0]
    lat = np.array(record.latencies_s) * 1e3
    from thermal_comp.view.run import bag_to_rrd  # heavy: rerun only when writing the .rrd
    (out / "graph.rrd").unlink(missing_ok=True)
    t0 = time.perf_counter()
    messages, _ = bag_to_rrd(out / "bag", out / "graph.rrd")     # what the demo writes after its graph
    rrd_s = time.perf_counter() - t0
    return {
        "scenario": f"{cfg.machine}/{cfg.scenario}", "simulated_h": round(record.sim_end_s / 3600.0, 2),
        "wall_s": round(record.wall_s, 1), "times_real_time": round(record.sim_end_s / record.wall_s, 1),
        "latency_temperature_to_offsets_ms": {"p50": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
                                              "p99": round(float(np.percentile(lat, 99)), 2) if lat.size else None,
                                              "samples": int(lat.size)},
        "peak_rss_mb": {k: round(v, 1) for k, v in record.peak_rss_mb.items()},
        "cpu_s": {**{k: round(v, 1) for k, v in record.cpu_s.items()},
                  "demo process (launcher, monitor)": round(sum(psutil.Process().cpu_times()[:2]), 1)},
        "bag_to_rrd": {"messages": messages, "wall_s": round(rrd_s, 2),
                       "messages_per_s": round(messages / rrd_s) if rrd_s > 0 else None},
        "instant_stages": record.stages,
        "acknowledgement_after_twin_ms": record.acks,
        "latency_parts": record.latency_parts,
        "executor": os.environ.get(rt.EXECUTOR_ENV, "single"),
        "niceness": record.niceness,
        # other processes on the 2 cores set the latency's tail: say how busy the machine was
        "load_average_1min_before_after": [round(load_before, 2), round(load_after, 2)],
    }
