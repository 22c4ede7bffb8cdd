"""Run a compensated machine cell end to end on the built-in twin (no hardware needed).

``thermal-comp demo [--machine nmv5000|swiss-lathe] [--scenario S] [--out DIR]`` starts the
whole graph as separate ROS 2 processes under the launcher, in its own ROS_DOMAIN_ID:
machine_sim (the twin, owner of simulated time, in lock-step), temperature_publisher,
probe_cycle, talc_model (TALC on the 5-axis machine, AGP on the lathe), cnc_bridge talking
OPC UA to the CNC emulator (a separate process), the bag recorder, and the rerun viewer when
a display exists. It shows a progress bar in simulated time and ends with the table of
uncompensated versus compensated P99 per error component beside the thesis's Table 6.5,
and writes the bag, an .rrd, ``summary.json`` and a PNG.

How "compensated" is computed: during [t_k, t_k+1) the CNC holds the offsets derived from
the prediction for t_k, so the error left on a part at t_k+1 is the true error at t_k+1 minus
that prediction (in component space). The bridge's limits are reported separately.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import shutil
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from thermal_comp_common.components import FIVE_AXIS_COMPONENTS

#: Published results the demo is compared with (Blaser thesis, Tables 6.5 and 6.7; P99).
THESIS_TABLES = {
    "talc-178h-dry": {
        "title": "thesis Table 6.5 (178 h, dry)",
        "p99_uncompensated": {"E_X0C": 4.4, "E_Y0C": 24.4, "E_Z0T": 27.5, "E_R0T": 8.5,
                              "E_A0C": 18.8, "E_B0C": 6.3, "E_C0C": 9.4},
        "p99_compensated": {"E_X0C": 2.7, "E_Y0C": 4.9, "E_Z0T": 6.1, "E_R0T": 2.9,
                            "E_A0C": 7.2, "E_B0C": 5.6, "E_C0C": 7.0},
    },
    "talc-144h-mwf": {
        "title": "thesis Table 6.7 (144 h, MWF)",
        "p99_uncompensated": {"E_Y0C": 43.4, "E_Z0T": 42.1},
        "p99_compensated": {"E_Y0C": 5.1},
    },
}

#: What each built-in machine runs.
MACHINES: dict[str, dict[str, Any]] = {
    "nmv5000": {"scenario": "talc-178h-dry", "model_kind": "talc", "artefact": "sphere",
                "sensor_config": "nmv5000", "step_s": 300.0, "compensation_mode": "kinematic",
                "model_config": "talc_nmv5000.yaml",
                "offset_axes": list(FIVE_AXIS_COMPONENTS)},
    "swiss-lathe": {"scenario": "lathe-random-speed", "model_kind": "agp", "artefact": "guide_bush",
                    "sensor_config": "swiss_lathe", "step_s": 60.0, "tool_position": "GB",
                    "offset_axes": ["GB_X"]},
}


class DemoError(RuntimeError):
    """The demo could not run; the message says which part failed."""


@dataclass
class DemoConfig:
    machine: str = "nmv5000"
    scenario: str | None = None
    hours: float | None = None
    seed: int = 0
    step_s: float | None = None
    out_dir: pathlib.Path = pathlib.Path("demo_out")
    view: str = "auto"                 # auto | live | rrd | none
    cnc: str = "opcua"                 # opcua | twin
    progress: bool = True
    wall_timeout_s: float = 3600.0
    #: restart policy of every node (cell-file ``restart`` mapping); None = no restarts
    restart: dict[str, Any] | None = None


@dataclass
class RunRecord:
    """What the demo's monitor saw while the graph ran (wall-time figures for the benchmark)."""

    sim_end_s: float = 0.0
    wall_s: float = 0.0
    latencies_s: list[float] = field(default_factory=list)
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    node_exit_codes: dict[str, list[int]] = field(default_factory=dict)
    restarts: dict[str, int] = field(default_factory=dict)


# --------------------------------------------------------------------------------------
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


def scenario_hours(machine: str, scenario: str, hours: float | None) -> float:
    from thermal_twin.scenarios import SCENARIOS, make_timeline
    make_timeline(machine, scenario, hours=hours or None, step_s=3600.0)  # validates the pair
    return float(hours) if hours else float(SCENARIOS[scenario].hours)


def build_cell(cfg: DemoConfig, domain_id: int, endpoint: str | None, live_view: bool) -> dict:
    """The cell document of the demo graph (the same format as `thermal-comp launch`)."""
    m = MACHINES[cfg.machine]
    out = cfg.out_dir.resolve()
    step = cfg.step_s or m["step_s"]
    participants = ["sensors", "model", "bridge"]
    model_params: dict[str, Any] = {"model_kind": m["model_kind"], "state_path": str(out / "model_state.json"),
                                    "lockstep_participant": True, "artefact": m["artefact"]}
    if m.get("tool_position"):
        model_params["tool_position"] = m["tool_position"]
    if m.get("model_config"):   # shipped with talc_model: the thesis's parameter set for this machine
        import talc_model
        model_params["model_config"] = str(pathlib.Path(talc_model.__file__).with_name("config") / m["model_config"])
    bridge: dict[str, Any] = {"lockstep": True, "audit_log_path": str(out / "cnc_audit.log"),
                              "backend": cfg.cnc}
    if m.get("offset_axes"):
        bridge["offset_axes"] = m["offset_axes"]
    if m.get("compensation_mode"):
        bridge["compensation_mode"] = m["compensation_mode"]
    if endpoint:
        bridge["endpoint"] = endpoint
    nodes = [
        {"name": "machine_sim", "module": "thermal_twin.machine_sim_node",
         "parameters": {"machine": cfg.machine, "scenario": cfg.scenario, "seed": cfg.seed,
                        "hours": float(cfg.hours or 0.0), "step_s": float(step),
                        "lockstep_participants": participants, "shutdown_when_done": True,
                        # the recorder is no lock-step participant; the first instant waits for it
                        "wait_for_subscribers": ["recorder"],
                        "state_path": str(out / "twin_state.pkl")}},
        {"name": "sensors", "module": "thermal_sensors.temperature_publisher_node",
         "parameters": {"source": "twin", "sensor_config": m["sensor_config"], "lockstep_participant": True}},
        {"name": "probe_cycle", "module": "probe_cycle.probe_cycle_node", "parameters": {"backend": "twin"}},
        {"name": "model", "module": "talc_model.talc_model_node", "parameters": model_params},
        {"name": "bridge", "module": "cnc_bridge.cnc_bridge_node", "parameters": bridge},
        {"name": "recorder", "module": "thermal_comp.bag_recorder_node",
         "parameters": {"output": str(out / "bag")}},
    ]
    if live_view:
        nodes.append({"name": "viewer", "module": "thermal_comp.rerun_view_node", "parameters": {}})
    cell = {"cell": "demo", "domain_id": domain_id, "use_sim_time": True, "nodes": nodes}
    if cfg.restart is not None:
        cell["restart"] = dict(cfg.restart)
    return cell


class _Monitor:
    """In-process node: follows /clock for the progress bar and measures the latency from a
    temperature message to the offsets answering the same instant (wall time)."""

    def __init__(self, namespace: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rosgraph_msgs.msg import Clock

        from thermal_comp_common import node_runtime as rt
        from thermal_comp_msgs.msg import AxisOffsets, TemperatureArray
        self.ctx = rclpy.context.Context()
        rclpy.init(args=[], context=self.ctx)
        self.node = rclpy.create_node("demo_monitor", namespace=namespace, context=self.ctx,
                                      start_parameter_services=False)
        self.sim_s = 0.0
        self.temp_wall: dict[int, float] = {}
        self.latencies: list[float] = []
        self.node.create_subscription(Clock, "/clock", self._on_clock, 10)
        self.node.create_subscription(TemperatureArray, rt.TOPIC_TEMPERATURES, self._on_temp, rt.SENSOR_QOS)
        self.node.create_subscription(AxisOffsets, rt.TOPIC_OFFSETS, self._on_offsets, rt.EVENT_QOS)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True, name="demo-monitor")
        self.thread.start()

    @staticmethod
    def _ns(stamp) -> int:
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    def _on_clock(self, msg) -> None:
        self.sim_s = max(self.sim_s, msg.clock.sec + msg.clock.nanosec * 1e-9)

    def _on_temp(self, msg) -> None:
        self.temp_wall.setdefault(self._ns(msg.header.stamp), time.perf_counter())

    def _on_offsets(self, msg) -> None:
        t0 = self.temp_wall.pop(self._ns(msg.header.stamp), None)
        if t0 is not None:
            self.latencies.append(time.perf_counter() - t0)

    def _spin(self) -> None:
        while not self._stop.is_set() and self.ctx.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        if self.ctx.ok():
            self.ctx.try_shutdown()


def _rss_tree_mb(pid: int) -> float:
    import psutil
    try:
        p = psutil.Process(pid)
        procs = [p] + p.children(recursive=True)
        return sum(q.memory_info().rss for q in procs if q.is_running()) / 2**20
    except psutil.Error:
        return 0.0


def run_graph(cfg: DemoConfig, on_poll=None) -> RunRecord:
    """Run the demo graph until the twin's scenario ends; return what was observed.

    ``on_poll(launcher, sim_s)``, if given, is called on every supervision poll (about 4 Hz)
    with the launcher and the simulated time seen so far (fault injection uses it)."""
    from thermal_comp.cell_config import parse_cell
    from thermal_comp_common.domain_ids import claim_domain_id
    from thermal_comp.launcher import Launcher

    out = cfg.out_dir.resolve()
    if (out / "bag").exists():
        shutil.rmtree(out / "bag")
    for stale in ("model_state.json", "cnc_audit.log", "twin_state.pkl"):
        (out / stale).unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    total_h = scenario_hours(cfg.machine, cfg.scenario, cfg.hours)
    domain_id = claim_domain_id()
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_LOG_DIR", str(out / "logs" / "ros"))
    live_view = cfg.view == "live" or (cfg.view == "auto" and bool(os.environ.get("DISPLAY")))

    emulator = None
    endpoint = None
    log_dir = out / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    if cfg.cnc == "opcua":
        port = _free_port()
        endpoint = f"opc.tcp://127.0.0.1:{port}/thermal-comp/cnc"
        emu_log = open(log_dir / "cnc_emulator.log", "w")
        axes = MACHINES[cfg.machine].get("offset_axes")
        emulator = subprocess.Popen([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--port", str(port)]
                                    + (["--compensation-axes", ",".join(axes)] if axes else []),
                                    stdout=emu_log, stderr=subprocess.STDOUT, start_new_session=True)
        _wait_port(port, emulator, 60.0)

    cell = parse_cell(build_cell(cfg, domain_id, endpoint, live_view), source="demo cell")
    print(f"demo graph: namespace /{cell.cell}, ROS_DOMAIN_ID {domain_id} (inspect with: thermal-comp topics "
          f"--domain-id {domain_id}); node logs: {log_dir / 'nodes.log'}", flush=True)
    node_log = open(log_dir / "nodes.log", "w")
    launcher = Launcher([cell], run_dir=log_dir / "run", output=node_log, grace_s=10.0)
    record = RunRecord()
    monitor = None
    bar = None
    t_start = time.perf_counter()
    try:
        launcher.start()
        monitor = _Monitor("/" + cell.cell)
        if cfg.progress:
            from tqdm import tqdm
            bar = tqdm(total=round(total_h, 2), unit="sim h", desc=f"{cfg.machine} {cfg.scenario}",
                       bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} sim h [{elapsed}<{remaining}]")
        sim_proc = next(mp for mp in launcher.processes if mp.node.name == "machine_sim")
        deadline = time.monotonic() + cfg.wall_timeout_s
        while True:
            launcher.poll()
            for mp in launcher.processes:
                if mp.pid:
                    record.peak_rss_mb[mp.node.name] = max(record.peak_rss_mb.get(mp.node.name, 0.0),
                                                           _rss_tree_mb(mp.pid))
            if on_poll is not None:
                on_poll(launcher, monitor.sim_s)
            if bar is not None:
                bar.n = round(min(monitor.sim_s / 3600.0, total_h), 2)
                bar.refresh()
            if sim_proc.popen.poll() is not None:
                launcher.poll()    # handle the exit first: a crash may be due for a restart
            if sim_proc.popen.poll() is not None and sim_proc.next_start is None:
                if sim_proc.popen.returncode != 0:
                    raise DemoError(f"machine_sim exited with code {sim_proc.popen.returncode}; "
                                    f"see {log_dir / 'nodes.log'}")
                break
            crashed = [mp.label for mp in launcher.processes if mp.gave_up or
                       (mp.popen and mp.popen.poll() not in (None, 0) and not mp.node.restart.enabled)]
            if crashed:
                raise DemoError(f"node(s) {crashed} crashed; see {log_dir / 'nodes.log'}")
            if time.monotonic() > deadline:
                raise DemoError(f"the graph did not finish within {cfg.wall_timeout_s:.0f} s wall time "
                                f"(reached {monitor.sim_s / 3600:.1f} of {total_h:.1f} sim h)")
            time.sleep(0.25)
        record.wall_s = time.perf_counter() - t_start
        record.sim_end_s = monitor.sim_s
    finally:
        if bar is not None:
            bar.close()
        launcher.request_stop()
        launcher.stop()
        if monitor is not None:
            record.latencies_s = list(monitor.latencies)
            monitor.close()
        if emulator is not None:
            emulator.terminate()
            try:
                emulator.wait(timeout=10)
            except subprocess.TimeoutExpired:
                emulator.kill()
        node_log.close()
    record.node_exit_codes = {mp.node.name: mp.exit_codes for mp in launcher.processes}
    record.restarts = {mp.node.name: mp.restarts for mp in launcher.processes}
    return record


# --------------------------------------------------------------------------------------
@dataclass
class DemoSeries:
    """Time series decoded from the demo's bag."""

    components: list[str]
    units: dict[str, str]
    t_true: np.ndarray
    true: dict[str, np.ndarray]
    t_pred: np.ndarray
    predicted: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    probe_times_s: list[float]
    t_applied: np.ndarray                 # stamps of the offsets messages
    applied: dict[str, np.ndarray]        # compensation the CNC held, per component (kinematic mode)
    status: dict[str, Any]
    phases: list[tuple[float, int]]
    limit_hits: int
    offsets_published: int


def read_series(bag_path: pathlib.Path) -> DemoSeries:
    """Decode ground truth, predictions, measurements, status and offsets from the demo bag."""
    from rclpy.serialization import deserialize_message

    from thermal_comp_common.bag_reader import read_bag
    from thermal_comp_msgs.msg import AxisOffsets, ModelStatus, ThermalErrors
    contents = read_bag(bag_path)
    if contents.damage:
        print(f"warning: bag damaged: {contents.damage}", file=sys.stderr)
    true_rows: dict[float, dict[str, float]] = {}
    pred_rows: dict[float, tuple[dict[str, float], dict[str, float]]] = {}
    probes: list[float] = []
    status: ModelStatus | None = None
    phases: list[tuple[float, int]] = []
    units: dict[str, str] = {}
    components: list[str] = []
    limit_hits = 0
    n_offsets = 0
    applied_rows: dict[float, dict[str, float]] = {}
    for m in contents.messages:
        topic = m.topic.rsplit("/", 2)
        name = "/".join(topic[-2:]) if m.topic.endswith(("errors/ground_truth", "errors/predicted",
                                                           "errors/measured")) else topic[-1]
        if name in ("errors/ground_truth", "errors/predicted", "errors/measured"):
            msg = deserialize_message(m.data, ThermalErrors)
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            vals = dict(zip(msg.component_names, msg.values))
            if name == "errors/ground_truth":
                true_rows[t] = vals
                for c, u in zip(msg.component_names, msg.units):
                    units[c] = "um/m" if u == ThermalErrors.UNIT_UM_PER_M else "um"
                    if c not in components:
                        components.append(c)
            elif name == "errors/predicted":
                pred_rows[t] = (vals, dict(zip(msg.component_names, msg.uncertainties)))
            else:
                probes.append(t)
        elif name == "model_status":
            status = deserialize_message(m.data, ModelStatus)
            t = status.header.stamp.sec + status.header.stamp.nanosec * 1e-9
            if not phases or phases[-1][1] != status.phase:
                phases.append((t, status.phase))
        elif name == "offsets":
            msg = deserialize_message(m.data, AxisOffsets)
            n_offsets += 1
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            applied_rows[t] = {a: (v if msg.compensation_enabled else 0.0)
                               for a, v in zip(msg.axis_names, msg.applied_offsets_um)}
            limit_hits += int(any(msg.limits_hit))
    if not true_rows:
        raise DemoError(f"{bag_path}: no ground-truth errors recorded")
    tt = np.array(sorted(true_rows))
    tp = np.array(sorted(pred_rows))
    true = {c: np.array([true_rows[t].get(c, math.nan) for t in tt]) for c in components}
    pred = {c: np.array([pred_rows[t][0].get(c, math.nan) for t in tp]) for c in components}
    std = {c: np.array([pred_rows[t][1].get(c, math.nan) for t in tp]) for c in components}
    st = {}
    if status is not None:
        st = {"phase": int(status.phase), "probing_cycles": int(status.probing_cycles),
              "failed_probing_cycles": int(status.failed_probing_cycles),
              "no_good_phases": int(status.no_good_phases), "parameter_updates": int(status.parameter_updates),
              "q_prod_pct": float(status.q_prod_pct), "model_kind": status.model_kind}
    ta = np.array(sorted(applied_rows))
    applied = {c: np.array([applied_rows[t].get(c, math.nan) for t in ta]) for c in components}
    if not any(np.isfinite(v).any() for v in applied.values()):
        applied = {}   # axis-offset mode: no per-component record of what the CNC held
    return DemoSeries(components, units, tt, true, tp, pred, std, sorted(set(probes)), ta, applied, st,
                      phases, limit_hits, n_offsets)


def compensation_in_effect(series: DemoSeries) -> dict[str, np.ndarray]:
    """Per ground-truth instant, the compensation the CNC held: the applied (read-back)
    values of the latest offsets stamped strictly before that instant when the CNC holds
    components (kinematic mode), else the latest prediction; zero before the first."""
    if series.applied:
        stamps, source = series.t_applied, series.applied
    else:
        stamps, source = series.t_pred, series.predicted
    idx = np.searchsorted(stamps, series.t_true, side="left") - 1
    out = {}
    for c in series.components:
        p = source[c]
        vals = np.where(idx >= 0, p[np.clip(idx, 0, None)] if p.size else 0.0, 0.0)
        out[c] = np.where(np.isfinite(vals), vals, 0.0)
    return out


def evaluation_start_s(series: DemoSeries) -> float:
    """Start of the compensation period: the first instant the model left its calibration
    phase (the thesis evaluates compensation after the calibration phase; during it nothing
    is compensated). The whole run if the model never left calibration."""
    for t, phase in series.phases:
        if phase != 0:
            return t
    return float(series.t_true[0])


def summarise(series: DemoSeries, cfg: DemoConfig, record: RunRecord | None) -> dict[str, Any]:
    from thermal_comp_common import metrics
    comp = compensation_in_effect(series)
    t_eval = evaluation_start_s(series)
    window = series.t_true >= t_eval
    errors = {}
    for c in series.components:
        e = series.true[c]
        ok = np.isfinite(e) & window
        if not ok.any():
            continue
        unc = metrics.p99(e[ok], np.zeros(ok.sum()))
        cmp_ = metrics.p99(e[ok], comp[c][ok])
        errors[c] = {"unit": series.units[c], "p99_uncompensated": round(unc, 3), "p99_compensated": round(cmp_, 3),
                     "reduction_pct": round(100.0 * (1.0 - cmp_ / unc), 1) if unc > 0 else None}
    hours = float(series.t_true[-1] - series.t_true[0]) / 3600.0
    summary = {
        "machine": cfg.machine, "scenario": cfg.scenario, "seed": cfg.seed, "simulated_hours": round(hours, 2),
        "evaluation_window_h": [round(t_eval / 3600.0, 2), round(float(series.t_true[-1]) / 3600.0, 2)],
        "model_kind": series.status.get("model_kind", MACHINES[cfg.machine]["model_kind"]),
        "errors": errors,
        "probing_cycles": series.status.get("probing_cycles", len(series.probe_times_s)),
        "failed_probing_cycles": series.status.get("failed_probing_cycles", 0),
        "no_good_phases": series.status.get("no_good_phases", 0),
        "parameter_updates": series.status.get("parameter_updates", 0),
        "q_prod_pct": round(series.status.get("q_prod_pct", float("nan")), 2),
        "offsets_limited_steps": series.limit_hits, "offsets_published": series.offsets_published,
    }
    if record is not None and record.wall_s > 0:
        summary["wall_time_s"] = round(record.wall_s, 1)
        summary["times_real_time"] = round(record.sim_end_s / record.wall_s, 1)
    if cfg.scenario in THESIS_TABLES:
        summary["thesis"] = THESIS_TABLES[cfg.scenario]
    return summary


def print_table(summary: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table
    thesis = summary.get("thesis", {})
    w0, w1 = summary["evaluation_window_h"]
    t = Table(title=f"{summary['machine']} / {summary['scenario']}: P99 of the thermal errors, "
                    f"{summary['model_kind'].upper()}, {summary['simulated_hours']} h simulated "
                    f"(evaluated {w0:g}-{w1:g} h, after the calibration phase)")
    t.add_column("error")
    t.add_column("unit")
    t.add_column("uncompensated", justify="right")
    t.add_column("compensated", justify="right")
    t.add_column("reduction", justify="right")
    if thesis:
        t.add_column(f"{thesis['title']}: uncomp. / comp.", justify="right")
    for c, e in summary["errors"].items():
        row = [c, e["unit"], f"{e['p99_uncompensated']:.1f}", f"{e['p99_compensated']:.1f}",
               f"{e['reduction_pct']:.0f} %" if e["reduction_pct"] is not None else "-"]
        if thesis:
            u = thesis["p99_uncompensated"].get(c)
            k = thesis["p99_compensated"].get(c)
            row.append(f"{u if u is not None else '-'} / {k if k is not None else '-'}")
        t.add_row(*row)
    c = Console()
    c.print(t)
    c.print(f"probing cycles {summary['probing_cycles']} (failed {summary['failed_probing_cycles']}), "
            f"no-good phases {summary['no_good_phases']}, parameter updates {summary['parameter_updates']}, "
            f"Q_prod {summary['q_prod_pct']} %"
            + (f"; thesis (§6.4.2): 4 no-good events from E_Y0C, 4 from E_Z0T, Q_prod about 97 % at the end"
               if summary["scenario"] == "talc-178h-dry" else ""))
    if "wall_time_s" in summary:
        c.print(f"wall time {summary['wall_time_s']} s ({summary['times_real_time']} x real time)")


def plot(series: DemoSeries, summary: dict[str, Any], path: pathlib.Path) -> None:
    """One panel per error: uncompensated, compensated, prediction band, probing instants
    and no-good phases (like the thesis's Figs 6.13-6.19)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    comp = compensation_in_effect(series)
    n = len(series.components)
    fig, axes = plt.subplots(n, 1, figsize=(12, 2.1 * n + 0.6), sharex=True, squeeze=False)
    th = series.t_true / 3600.0
    ng_spans = []
    for i, (t0, ph) in enumerate(series.phases):
        if ph == 2:
            t1 = series.phases[i + 1][0] if i + 1 < len(series.phases) else series.t_true[-1]
            ng_spans.append((t0 / 3600.0, t1 / 3600.0))
    for ax, c in zip(axes[:, 0], series.components):
        e = series.true[c]
        ax.plot(th, e, color="0.55", lw=1.0, label="uncompensated (twin truth)")
        ax.plot(th, e - comp[c], color="tab:blue", lw=1.0, label="compensated")
        if series.t_pred.size:
            tp = series.t_pred / 3600.0
            p, s = series.predicted[c], series.std[c]
            ax.plot(tp, p, color="tab:orange", lw=0.8, label="prediction")
            ok = np.isfinite(s)
            if ok.any():
                ax.fill_between(tp[ok], (p - 2 * s)[ok], (p + 2 * s)[ok], color="tab:orange", alpha=0.2,
                                lw=0, label="prediction ±2u")
        for t in series.probe_times_s:
            ax.axvline(t / 3600.0, color="tab:green", lw=0.4, alpha=0.5)
        for a, b in ng_spans:
            ax.axvspan(a, b, color="tab:red", alpha=0.12)
        es = summary["errors"].get(c, {})
        ax.set_ylabel(f"{c}\n[{series.units[c]}]")
        ax.set_title(f"{c}: P99 {es.get('p99_uncompensated', float('nan')):.1f} -> "
                     f"{es.get('p99_compensated', float('nan')):.1f} {series.units[c]}", fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=4)
    axes[-1, 0].set_xlabel("time [h]   (green: probing cycles, red: no-good phases)")
    fig.suptitle(f"{summary['machine']} / {summary['scenario']}: {summary['model_kind'].upper()} compensation, "
                 f"{summary['probing_cycles']} probing cycles, Q_prod {summary['q_prod_pct']} %")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_rrd(bag: pathlib.Path, rrd: pathlib.Path) -> int:
    import rerun as rr

    from thermal_comp_common.bag_reader import read_bag
    from thermal_comp.view_cli import log_bag
    rec = rr.RecordingStream("thermal_comp_demo")
    rec.save(str(rrd))
    n, damage = log_bag(read_bag(bag), rec, progress=False)
    rec.flush()
    if damage:
        print(f"warning: {damage}", file=sys.stderr)
    return n


def run_demo(cfg: DemoConfig) -> dict[str, Any]:
    """Run the graph, then write summary.json, the PNG and the .rrd; return the summary."""
    if cfg.machine not in MACHINES:
        raise DemoError(f"--machine: {cfg.machine!r} is not one of {sorted(MACHINES)}")
    cfg.scenario = cfg.scenario or MACHINES[cfg.machine]["scenario"]
    record = run_graph(cfg)
    out = cfg.out_dir.resolve()
    series = read_series(out / "bag")
    summary = summarise(series, cfg, record)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot(series, summary, out / "compensation.png")
    write_rrd(out / "bag", out / "demo.rrd")
    return summary


def main(argv: list[str] | None = None) -> int:
    """Run a compensated machine cell end to end on the built-in twin (no hardware)."""
    ap = argparse.ArgumentParser(prog="thermal-comp demo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--machine", default="nmv5000", choices=sorted(MACHINES), help="built-in twin preset")
    ap.add_argument("--scenario", help="twin scenario (default: talc-178h-dry for nmv5000, "
                                       "lathe-random-speed for swiss-lathe)")
    ap.add_argument("--hours", type=float, help="shorten the scenario to this many simulated hours")
    ap.add_argument("--seed", type=int, default=0, help="seed of the scenario and the sensor noise")
    ap.add_argument("--step", type=float, dest="step_s",
                    help="simulation step in s (default 300 s on nmv5000, the thesis's 5-min grid)")
    ap.add_argument("--out", default="demo_out", help="output folder (bag, demo.rrd, summary.json, PNG, logs)")
    ap.add_argument("--view", choices=("auto", "live", "rrd", "none"), default="auto",
                    help="auto: live rerun viewer when a display exists, else an .rrd file (always written)")
    ap.add_argument("--cnc", choices=("opcua", "twin"), default="opcua",
                    help="opcua: the bridge writes to the CNC emulator over OPC UA (default); twin: directly")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--wall-timeout", type=float, default=3600.0, help="give up after this many wall seconds")
    a = ap.parse_args(argv)
    cfg = DemoConfig(machine=a.machine, scenario=a.scenario, hours=a.hours, seed=a.seed, step_s=a.step_s,
                     out_dir=pathlib.Path(a.out), view=a.view, cnc=a.cnc, progress=not a.no_progress,
                     wall_timeout_s=a.wall_timeout)
    try:
        summary = run_demo(cfg)
    except (DemoError, ValueError) as exc:
        print(f"thermal-comp demo: {exc}", file=sys.stderr)
        return 1
    print_table(summary)
    out = cfg.out_dir.resolve()
    print(f"written: {out / 'summary.json'}, {out / 'compensation.png'}, {out / 'demo.rrd'}, {out / 'bag'}")
    return 0


# --------------------------------------------------------------------------------------
def bench_graph(args) -> dict[str, Any]:
    """Whole-graph closed-loop speed (x real time), temperature->offsets latency, peak memory per node."""
    hours = 12.0 if getattr(args, "quick", False) else None
    out = pathlib.Path(getattr(args, "out_dir", "bench_out")) / "graph"
    cfg = DemoConfig(out_dir=out, hours=hours, view="rrd", progress=True)
    cfg.scenario = MACHINES[cfg.machine]["scenario"]
    record = run_graph(cfg)
    lat = np.array(record.latencies_s) * 1e3
    return {
        "scenario": f"{cfg.machine}/{cfg.scenario}", "simulated_h": round(record.sim_end_s / 3600.0, 2),
        "wall_s": round(record.wall_s, 1), "times_real_time": round(record.sim_end_s / record.wall_s, 1),
        "latency_temperature_to_offsets_ms": {"p50": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
                                              "p99": round(float(np.percentile(lat, 99)), 2) if lat.size else None,
                                              "samples": int(lat.size)},
        "peak_rss_mb": {k: round(v, 1) for k, v in record.peak_rss_mb.items()},
    }


if __name__ == "__main__":
    sys.exit(main())
