"""Fault injection for reliability tests and ``thermal-comp bench faults`` (no rclpy import).

Three kinds of tools, all plain Python/numpy:

- **sensor faults** on a stream of raw readings (:class:`SensorFault`, :func:`inject`):
  NaN, out of range, stuck value, spike, a sensor that disappears, and late / out-of-order
  delivery of whole frames (:func:`reorder_late`);
- **safety checks** on what reached a CNC (:func:`offset_violations`): every step of the
  applied offsets within the rate limit (``max_rate * min(dt, max_step) + tolerance``) and
  within the absolute limit;
- **process kills** of a running graph under the launcher (:class:`KillPlan`): ``kill -9``
  of a node's whole process group at a simulated instant, then the launcher's restart
  policy takes over; :func:`run_killed_graph` runs the demo graph with such a plan.

The policies these tools check are documented in docs/reliability.md.
"""
from __future__ import annotations

import math
import os
import signal
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from thermal_comp_common import metrics

FAULT_KINDS = ("nan", "out_of_range", "stuck", "spike", "disappear")


@dataclass(frozen=True)
class SensorFault:
    """One fault of one sensor over ``[t_start_s, t_end_s)`` (simulated time).

    ``nan``: the value reads NaN; ``out_of_range``: the value reads ``value`` (a reading
    outside the sensor's range); ``stuck``: the value freezes at the first faulty reading;
    ``spike``: ``value`` is added (one reading when the window holds one sample);
    ``disappear``: the sensor is missing from the frame.
    """

    sensor_id: str
    kind: str
    t_start_s: float
    t_end_s: float = math.inf
    value: float = 0.0

    def __post_init__(self):
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"SensorFault.kind: {self.kind!r} is not one of {list(FAULT_KINDS)}")
        if not self.t_end_s > self.t_start_s:
            raise ValueError(f"SensorFault {self.sensor_id}: t_end_s {self.t_end_s!r} must be after "
                             f"t_start_s {self.t_start_s!r}")

    def active(self, t_s: float) -> bool:
        return self.t_start_s <= t_s < self.t_end_s


class FaultInjector:
    """Applies :class:`SensorFault` s to frames ``{sensor_id: value}`` in time order."""

    def __init__(self, faults: Iterable[SensorFault]):
        self.faults = list(faults)
        self._stuck: dict[int, float] = {}
        self.injected = 0          # readings altered or removed
        self.counts = [0] * len(self.faults)   # per fault

    def apply(self, t_s: float, readings: Mapping[str, float]) -> dict[str, float]:
        out = dict(readings)
        for i, f in enumerate(self.faults):
            if not f.active(t_s) or f.sensor_id not in out:
                continue
            self.injected += 1
            self.counts[i] += 1
            if f.kind == "nan":
                out[f.sensor_id] = math.nan
            elif f.kind == "out_of_range":
                out[f.sensor_id] = float(f.value)
            elif f.kind == "stuck":
                out[f.sensor_id] = self._stuck.setdefault(i, out[f.sensor_id])
            elif f.kind == "spike":
                out[f.sensor_id] = out[f.sensor_id] + float(f.value)
            else:  # disappear
                del out[f.sensor_id]
        return out


def inject(times_s: Sequence[float], frames: Sequence[Mapping[str, float]],
           faults: Iterable[SensorFault]) -> list[dict[str, float]]:
    """The frames with ``faults`` applied (a new list; the input is not changed)."""
    inj = FaultInjector(faults)
    return [inj.apply(float(t), fr) for t, fr in zip(times_s, frames)]


def reorder_late(n: int, late: Mapping[int, int]) -> list[int]:
    """Delivery order of ``n`` frames when frame ``i`` arrives ``late[i]`` positions late.

    ``reorder_late(5, {1: 2})`` -> ``[0, 2, 3, 1, 4]``: frame 1 arrives after frames 2 and 3
    (out of order). Every index appears exactly once.
    """
    keys = [(i + late.get(i, 0) + (0.5 if late.get(i, 0) else 0.0), i) for i in range(n)]
    return [i for _, i in sorted(keys)]


# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OffsetViolation:
    """A step of the applied offsets that broke the envelope."""

    axis: str
    t_s: float
    previous_um: float
    applied_um: float
    allowed_step_um: float
    why: str

    def __str__(self) -> str:
        return (f"axis {self.axis} at t={self.t_s:.3f} s: {self.previous_um:+.4f} -> {self.applied_um:+.4f} um "
                f"({self.why}; allowed step {self.allowed_step_um:.4f} um)")


def offset_violations(times_s: Sequence[float], applied_um: Mapping[str, Sequence[float]],
                      max_rate_um_per_s: float, abs_limit_um: float, max_step_s: float = math.inf,
                      start_um: Mapping[str, float] | None = None,
                      tolerance_um: float = 1e-6) -> list[OffsetViolation]:
    """Every step of ``applied_um[axis]`` (sampled at ``times_s``) that moves faster than
    ``max_rate_um_per_s`` (the elapsed time capped at ``max_step_s``, as the envelope does)
    or exceeds ``abs_limit_um``. ``start_um`` is what the CNC held before the first sample
    (default 0). NaN samples (a write not confirmed) are skipped: the CNC kept the previous
    value. Samples at equal times must not change the value at all.
    """
    t = np.asarray(times_s, dtype=float)
    out: list[OffsetViolation] = []
    for axis, series in applied_um.items():
        v = np.asarray(series, dtype=float)
        if v.shape != t.shape:
            raise ValueError(f"applied_um[{axis!r}]: {v.size} samples for {t.size} times")
        prev = float((start_um or {}).get(axis, 0.0))
        prev_t = None
        for ti, vi in zip(t, v):
            if not math.isfinite(vi):
                continue
            if abs(vi) > abs_limit_um + tolerance_um:
                out.append(OffsetViolation(axis, float(ti), prev, float(vi), abs_limit_um, "absolute limit"))
            dt = 0.0 if prev_t is None else min(max(ti - prev_t, 0.0), max_step_s)
            allow = max_rate_um_per_s * dt + tolerance_um   # the first sample may not move at all
            if abs(vi - prev) > allow:
                out.append(OffsetViolation(axis, float(ti), prev, float(vi), allow, "rate limit"))
            prev, prev_t = float(vi), float(ti)
    return out


# --------------------------------------------------------------------------------------
@dataclass
class Kill:
    """``kill -9`` of node ``node`` once simulated time reaches ``at_sim_s``."""

    node: str
    at_sim_s: float
    done_wall: float | None = None
    pid: int | None = None
    restarted_pid: int | None = None


@dataclass
class KillPlan:
    """Kills to perform while a graph runs; call :meth:`poll` from the supervision loop."""

    kills: list[Kill] = field(default_factory=list)

    def poll(self, launcher, sim_s: float) -> None:
        import time
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
            elif k.done_wall is not None and k.restarted_pid is None and mp.running() and mp.pid != k.pid:
                k.restarted_pid = mp.pid

    @property
    def all_done(self) -> bool:
        return all(k.done_wall is not None for k in self.kills)


# --------------------------------------------------------------------------------------
@dataclass
class LoopResult:
    """What one closed loop of the pure cores produced (one row per instant)."""

    t_s: np.ndarray
    components: list[str]
    true: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]
    status: dict[str, np.ndarray]           # sensor id -> TemperatureArray.STATUS_* per instant
    excluded: list[list[str]]               # ModelStatus.excluded_sensor_ids per instant
    axes: list[str]
    applied_um: dict[str, np.ndarray]       # envelope output per axis
    flags: dict[str, np.ndarray]            # LIMIT_* flags per axis
    probing_cycles: int
    failed_probing_cycles: int
    no_good_phases: int
    injected: int
    injected_per_fault: list[int] = field(default_factory=list)

    def p99_compensated(self) -> dict[str, float]:
        """P99 of |true - prediction in effect| (the prediction of the previous instant)."""
        out = {}
        for c in self.components:
            e = self.true[c][1:]
            p = np.nan_to_num(self.predicted[c][:-1], nan=0.0)
            out[c] = metrics.p99(e, p)
        return out


def run_core_loop(faults: Iterable[SensorFault] = (), hours: float = 48.0, seed: int = 0,
                  step_s: float = 300.0, max_rate_um_per_s: float = 0.5, abs_limit_um: float = 30.0,
                  probe_failures: Iterable[float] = (), probe_outliers: Mapping[float, float] | None = None,
                  progress: bool = False) -> LoopResult:
    """The 5-axis cell's pure cores in a loop, without ROS: twin (nmv5000, talc-178h-dry)
    -> sensor faults -> TwinSource + TemperatureFrameBuilder (status) -> TALC (non-OK sensors
    as NaN, as the talc_model node does) -> offsets_from_errors -> SafetyEnvelope.

    Probing: when the model says so, the true errors minus the applied compensation are
    measured; a probing instant at or after a time in ``probe_failures`` fails instead (once
    per listed time, counted, not learned from); ``probe_outliers`` {time: um} adds that
    much to every linear component of the first measurement at or after the time (a bad fit
    that passed the cycle's own checks).
    """
    from cnc_bridge.error_transform import offsets_from_errors
    from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
    from talc_model.adaptive_model import ANGULAR_COMPONENTS, make_model
    from thermal_sensors.sensor_config import load_sensor_config, resolve_sensor_config
    from thermal_sensors.temperature_frame import TemperatureFrameBuilder
    from thermal_sensors.twin_source import TwinSource
    from thermal_twin.machine_schema import load_machine
    from thermal_twin.scenario_runner import ScenarioRunner
    from thermal_twin.scenarios import make_timeline
    import importlib.resources
    import yaml

    machine = load_machine("nmv5000")
    runner = ScenarioRunner(machine, make_timeline(machine.name, "talc-178h-dry", hours=hours, seed=seed,
                                                   step_s=step_s), seed=seed)
    config = load_sensor_config(resolve_sensor_config("nmv5000"))
    source, builder = TwinSource(config), TemperatureFrameBuilder(config)
    talc_yaml = importlib.resources.files("talc_model") / "config" / "talc_nmv5000.yaml"
    model = make_model("talc", yaml.safe_load(talc_yaml.read_text()))
    envelope = SafetyEnvelope(EnvelopeConfig(abs_limit_um=abs_limit_um, max_rate_um_per_s=max_rate_um_per_s,
                                             max_step_s=600.0))
    inj = FaultInjector(faults)
    fail_at = sorted(float(x) for x in probe_failures)
    outliers = dict(sorted((float(k), float(v)) for k, v in (probe_outliers or {}).items()))
    comps = list(model.component_names)
    rows_t, excluded_rows = [], []
    true = {c: [] for c in comps}
    pred = {c: [] for c in comps}
    status = {s: [] for s in config.sensor_ids}
    applied: dict[str, list[float]] = {}
    flags: dict[str, list[int]] = {}
    last_pred = {c: 0.0 for c in comps}
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(runner.timeline), unit="step", desc="core loop", leave=False)
    while True:
        t = runner.t_s
        raw = inj.apply(t, runner.sensor_readings())
        source.accept(t, list(raw), list(raw.values()))
        frame = builder.build(source.sample(t))
        temps, excl = {}, []
        for sid, v, st in zip(frame.sensor_ids, frame.temperatures_degc, frame.status):
            status[sid].append(int(st))
            ok = int(st) == 0 and math.isfinite(v)
            temps[sid] = float(v) if ok else math.nan
            if not ok:
                excl.append(sid)
        model.update_inputs(t, temps, {})
        values, _ = model.predict(t)
        errors_now = {k[:-3] if k.endswith("_um") else k: v for k, v in runner.errors().items()}
        if model.probe_due(t):
            if fail_at and t >= fail_at[0]:
                fail_at.pop(0)
                model.add_failed_measurement(t, "injected: cycle failed")
            else:
                measured = {c: errors_now[c] - last_pred.get(c, 0.0) for c in comps}
                if outliers and t >= next(iter(outliers)):
                    bad = outliers.pop(next(iter(outliers)))
                    measured = {c: v + (0.0 if c in ANGULAR_COMPONENTS else bad) for c, v in measured.items()}
                model.add_measurement(t, measured, dict(last_pred))
            values, _ = model.predict(t)
        excluded_rows.append(sorted(set(model.status(t).excluded_sensor_ids) | set(excl)))
        rows_t.append(t)
        for c in comps:
            true[c].append(errors_now[c])
            pred[c].append(values.get(c, math.nan))
        finite = {c: v for c, v in values.items() if math.isfinite(v)}
        last_pred = {c: finite.get(c, 0.0) for c in comps}
        commanded = offsets_from_errors(finite, {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}) if finite else None
        for d in envelope.step(t, commanded, fresh=commanded is not None):
            envelope.confirm(d.axis, d.applied_um)
            applied.setdefault(d.axis, [math.nan] * (len(rows_t) - 1)).append(d.applied_um)
            flags.setdefault(d.axis, [0] * (len(rows_t) - 1)).append(d.flags)
        if bar is not None:
            bar.update(1)
        if runner.done:
            break
        runner.step()
    if bar is not None:
        bar.close()
    st = model.status(rows_t[-1])
    return LoopResult(np.asarray(rows_t), comps, {c: np.asarray(v) for c, v in true.items()},
                      {c: np.asarray(v) for c, v in pred.items()}, {s: np.asarray(v) for s, v in status.items()},
                      excluded_rows, sorted(applied), {a: np.asarray(v) for a, v in applied.items()},
                      {a: np.asarray(v) for a, v in flags.items()}, st.probing_cycles,
                      st.failed_probing_cycles, st.no_good_phases, inj.injected, list(inj.counts))


# --------------------------------------------------------------------------------------
@dataclass
class LinkFaultResult:
    """One CNC-link fault: what the envelope and the CNC did around it."""

    fault: str
    survived: bool                 # writes confirmed again after the fault, offsets where commanded
    writes_failed: int             # writes flagged LIMIT_WRITE_FAILED during the fault
    violations: list[OffsetViolation]
    detail: str = ""


def written_offsets_um(write_log: Sequence[tuple[str, float]], axis: str, scale_um_per_unit: float = 1000.0
                       ) -> list[float]:
    """The offsets (um) written to ``axis``'s SD43900 node, in order, from an emulator write log."""
    suffix = f"TempComp.{axis}.SD43900"
    return [float(v) * scale_um_per_unit for nid, v in write_log if nid.endswith(suffix)]


def step_violations(values_um: Sequence[float], max_step_um: float, abs_limit_um: float, axis: str,
                    start_um: float = 0.0, tolerance_um: float = 1e-6) -> list[OffsetViolation]:
    """Consecutive values written to a CNC that differ by more than ``max_step_um`` (one
    envelope step's allowance) or exceed ``abs_limit_um``; index = write number."""
    out, prev = [], float(start_um)
    for i, v in enumerate(values_um):
        if abs(v) > abs_limit_um + tolerance_um:
            out.append(OffsetViolation(axis, float(i), prev, float(v), abs_limit_um, "absolute limit"))
        if abs(v - prev) > max_step_um + tolerance_um:
            out.append(OffsetViolation(axis, float(i), prev, float(v), max_step_um, "rate limit"))
        prev = float(v)
    return out


def run_link_fault(fault: str, port: int, steps_before: int = 12, steps_during: int = 4,
                   steps_after: int = 12, target_um: float = 8.0, max_rate_um_per_s: float = 0.1,
                   dt_s: float = 10.0) -> LinkFaultResult:
    """Drive SafetyEnvelope + OpcUaBackend against the CNC emulator (own thread) and inject
    ``fault`` between ``steps_before`` and ``steps_before + steps_during`` envelope steps:

    - ``server_restart``: the OPC UA server stops and starts again with its state;
    - ``server_reset``: the server restarts with its compensation reset to zero (a CNC reboot);
    - ``stalled``: the server is gone for the whole fault window (connection stalls), then back;
    - ``wrong_credentials``: the server requires a user the bridge does not log in as;
    - ``rejected_write``: the CNC refuses writes of X's offset node (made read-only on the
      server: BadNotWritable) for the fault window;
    - ``bridge_restart``: a new backend and envelope (a restarted bridge process) take over
      while the CNC holds an offset.

    The envelope's command ramps to ``target_um`` on axis X (and Y). Unsafe = any value
    written to the CNC that moves by more than ``max_rate * dt`` from the previous write.
    """
    import time
    from cnc_bridge.cnc_emulator import CncEmulatorThread, EmulatorConfig
    from cnc_bridge.opcua_backend import OpcUaBackend, OpcUaConfig, default_node_map
    from cnc_bridge.safety_envelope import LIMIT_WRITE_FAILED, EnvelopeConfig, SafetyEnvelope

    endpoint = f"opc.tcp://127.0.0.1:{port}/thermal-comp/cnc"
    emu_cfg = EmulatorConfig(port=port, compensation_axes=("X", "Y"),
                             **({"user": "cnc", "password": "s3cret"} if fault == "wrong_credentials" else {}))
    axes = ("X", "Y")
    node_map = dict(default_node_map(axes))
    env_cfg = EnvelopeConfig(abs_limit_um=30.0, max_rate_um_per_s=max_rate_um_per_s, max_step_s=dt_s,
                             watchdog_timeout_s=1e6)

    def make_backend(**kw):
        return OpcUaBackend(OpcUaConfig(endpoint=endpoint, node_map=node_map, timeout_s=1.0,
                                        check_period_s=0.2, reconnect_min_s=0.1, reconnect_max_s=0.5, **kw))

    emu = CncEmulatorThread(emu_cfg).start()
    backend = None
    failed = 0
    try:
        creds = {"user": "cnc", "password": "wrong"} if fault == "wrong_credentials" else {}
        backend = make_backend(**creds)
        backend.wait_connected(1.0 if fault == "wrong_credentials" else 10.0)
        env = SafetyEnvelope(env_cfg)
        t = 0.0

        def step(during: bool) -> None:
            nonlocal t, failed
            t += dt_s
            decisions = env.step(t, {a: target_um for a in axes}, fresh=True)
            back = backend.write_offsets({d.axis: d.applied_um for d in decisions})
            for d in decisions:
                env.confirm(d.axis, back.get(d.axis))
                if back.get(d.axis) is None and during:
                    failed += 1

        for _ in range(steps_before):
            step(False)
        if fault in ("server_restart", "server_reset"):
            emu.restart(keep_state=fault == "server_restart")
        elif fault == "stalled":
            emu.stop()
        elif fault == "rejected_write":
            _set_writable(emu, node_map["X"].offset, False)
        elif fault == "bridge_restart":
            backend.close()
            backend = make_backend()
            backend.wait_connected(10.0)
            env = SafetyEnvelope(env_cfg)
        for _ in range(steps_during):
            step(True)
        if fault == "stalled":
            emu.start(emu.emulator.state)
        elif fault == "rejected_write":
            _set_writable(emu, node_map["X"].offset, True)
        if fault in ("server_restart", "server_reset", "stalled", "rejected_write"):
            backend.wait_connected(10.0)
        for _ in range(steps_after):
            step(False)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and fault != "wrong_credentials":
            if backend.connected:
                break
            time.sleep(0.05)
        applied = emu.applied_um()
        violations = []
        for a in axes:
            violations += step_violations(written_offsets_um(emu.write_log, a), max_rate_um_per_s * dt_s,
                                          env_cfg.abs_limit_um, a)
        if fault == "wrong_credentials":
            survived = not backend.connected and all(abs(v) < 1e-9 for v in applied.values())
            detail = f"refused: {backend.last_error}"
        else:
            survived = backend.connected and all(abs(applied[a] - env.applied[a]) < 1e-6 for a in axes)
            detail = f"CNC holds {', '.join(f'{a}={applied[a]:.3f}' for a in axes)} um"
        if fault != "wrong_credentials" and failed == 0 and fault != "bridge_restart":
            survived = False
            detail += "; the fault was not seen (no write failed during it)"
        return LinkFaultResult(fault, bool(survived), failed, violations, detail)
    finally:
        if backend is not None:
            backend.close()
        emu.close()


def _set_writable(emu, node_id: str, writable: bool) -> None:
    """Fault injection on the emulator's own server: make ``node_id`` (not) writable."""
    from asyncua import ua

    async def change():
        node = emu.emulator._server.get_node(ua.NodeId.from_string(node_id))
        await node.set_writable(writable)
    emu._run(change())


# --------------------------------------------------------------------------------------
#: The bridge's envelope in the demo cell (cnc_bridge_node defaults) for the audit-log check.
DEMO_ENVELOPE = {"max_rate_um_per_s": 0.5, "abs_limit_um": 30.0, "max_step_s": 600.0}


def run_graph_faults(out_dir, hours: float, kills: Sequence[Kill] = (), seed: int = 0,
                     wall_timeout_s: float = 600.0, progress: bool = False,
                     p99_until_h: float | None = None) -> dict:
    """The demo graph (nmv5000, talc-178h-dry shortened to ``hours``, OPC UA to the CNC
    emulator) under the launcher with restarts enabled, ``kills`` performed mid-run.

    Returns the demo summary plus what the faults did: restarts per node, whether the model
    resumed from its saved state (and never went back to calibration), instants that lack
    temperatures / predictions / offsets in the bag (data lost), bag damage, and audit-log
    writes that broke the bridge's envelope (unsafe writes).
    """
    import pathlib

    from cnc_bridge.audit_log import read_audit_log
    from rclpy.serialization import deserialize_message

    from thermal_comp_common.bag_reader import read_bag
    from thermal_comp.demo import DemoConfig, read_series, run_graph, summarise
    from thermal_comp_msgs.msg import ModelStatus

    out = pathlib.Path(out_dir)
    cfg = DemoConfig(out_dir=out, hours=hours, seed=seed, view="none", progress=progress, cnc="opcua",
                     wall_timeout_s=wall_timeout_s,
                     restart={"enabled": True, "max_restarts": 3, "backoff_s": 0.5})
    cfg.scenario = "talc-178h-dry"
    plan = KillPlan([Kill(k.node, k.at_sim_s) for k in kills])
    record = run_graph(cfg, on_poll=plan.poll)
    contents = read_bag(out / "bag")
    stamps: dict[str, set[int]] = {}
    probing, phases = [], []
    for m in contents.messages:
        name = m.topic.split("/", 2)[-1]
        stamps.setdefault(name, set()).add(m.log_time_ns)
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
    status_times = [m.log_time_ns for m in contents.messages if m.topic.endswith("model_status")]
    back_to_calibration = left_calibration is not None and any(
        p == ModelStatus.PHASE_CALIBRATION for p in phases[left_calibration:])
    counter_regressions = sum(1 for a, b in zip(probing, probing[1:]) if b < a)
    log_text = (out / "logs" / "nodes.log").read_text(errors="replace")
    rows = read_audit_log(out / "cnc_audit.log")
    times = sorted({float(r["time_s"]) for r in rows})
    index = {t: i for i, t in enumerate(times)}
    applied: dict[str, np.ndarray] = {}
    for r in rows:
        a = applied.setdefault(r["axis"], np.full(len(times), np.nan))
        a[index[float(r["time_s"])]] = float(r["applied_um"]) if r["applied_um"] else np.nan
    violations = offset_violations(times, applied, **DEMO_ENVELOPE)
    audited = {round(t, 3) for t in times}
    audit_missing = sorted(t / 1e9 for t in truth if t >= first_pred and round(t / 1e9, 3) not in audited)
    series = read_series(out / "bag")
    summary = summarise(series, cfg, record)
    p99_until = None
    if p99_until_h is not None:   # compensated P99 over the instants before p99_until_h only

        from thermal_comp.demo import compensation_in_effect
        comp = compensation_in_effect(series)
        keep = series.t_true < p99_until_h * 3600.0
        p99_until = {c: round(metrics.p99(series.true[c][keep], comp[c][keep]), 3) for c in series.components}
    return {
        "summary": summary,
        "kills": [{"node": k.node, "at_sim_h": round(k.at_sim_s / 3600.0, 2), "killed": k.done_wall is not None,
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
    import pathlib
    import subprocess
    import sys
    import time

    from thermal_comp_common.bag_reader import read_bag

    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")
    ns = ["--ros-args", "-r", "__ns:=/rec_kill"]
    sim = subprocess.Popen([sys.executable, "-m", "thermal_twin.machine_sim_node", *ns, "-p", "hours:=200.0",
                            "-p", "real_time_factor:=6000.0", "-p", "step_s:=300.0"],
                           env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    rec_argv = [sys.executable, "-m", "thermal_comp.bag_recorder_node", *ns, "-p", f"output:={bag}",
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


# --------------------------------------------------------------------------------------
class FaultyProbeBackend:
    """A probe backend that breaks one touch of a cycle: ``outlier`` (the skip position
    moved by ``value_um`` along the move), ``missing_trigger``, ``error`` (the backend
    raises), ``slow`` (the machine clock jumps by ``value_um`` seconds: a stalled cycle that
    runs into its timeout). Every other touch goes to ``inner``."""

    def __init__(self, inner, fault: str, at_touch: int = 3, value_um: float = 25.0):
        if fault not in ("outlier", "missing_trigger", "error", "slow"):
            raise ValueError(f"FaultyProbeBackend.fault: {fault!r} is not outlier, missing_trigger, error or slow")
        self.inner, self.fault, self.at_touch, self.value = inner, fault, int(at_touch), float(value_um)
        self.touches = 0
        self.name = f"faulty({getattr(inner, 'name', 'backend')})"
        self._clock_jump = 0.0

    def touch(self, move):
        from probe_cycle.probe_backend import ProbeBackendError, TouchReply
        i = self.touches
        self.touches += 1
        reply = self.inner.touch(move)
        if i != self.at_touch:
            return TouchReply(reply.triggered, reply.position_mm, reply.stamp_s + self._clock_jump, reply.message)
        if self.fault == "error":
            raise ProbeBackendError("injected: probe signal lost")
        if self.fault == "missing_trigger":
            return TouchReply(False, reply.position_mm, reply.stamp_s + self._clock_jump, "injected: no trigger")
        if self.fault == "slow":
            self._clock_jump += self.value
            return TouchReply(reply.triggered, reply.position_mm, reply.stamp_s + self._clock_jump, reply.message)
        d = np.asarray(move.direction, dtype=float)
        pos = np.asarray(reply.position_mm, dtype=float) + d / np.linalg.norm(d) * self.value * 1e-3
        return TouchReply(reply.triggered, pos, reply.stamp_s, reply.message)

    def close(self) -> None:
        self.inner.close()
