"""Fault harness: the whole 5-axis cell (twin, sensors, TALC, bridge) run without ROS, under faults.

Sensor and probe faults are injected into the pure cores of every node, wired as the cell wires them:
twin (nmv5000, talc-178h-dry) -> sensor faults -> TwinSource + TemperatureFrameBuilder
(status) -> :class:`talc_model.loop.closed_loop.ClosedLoop` with TALC (non-OK sensors as NaN, as
the talc_model node does) -> the bridge's write path, :class:`cnc_bridge.bridge_core.BridgeCore`
with the twin backend (:func:`run_core_loop`).
"""
from __future__ import annotations

import importlib.resources
import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np
import yaml
from tqdm import tqdm

from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.offset_backend import TwinBackend
from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
from talc_model.adaptive_model import ANGULAR_COMPONENTS, make_model
from talc_model.loop.closed_loop import ClosedLoop, HeldCompensation, ProbeFailed
from thermal_comp_common import metrics
from thermal_comp_common.sensor_readings import model_temperatures
from thermal_eval.reliability.sensor_faults import FaultInjector, SensorFault
from thermal_sensors.sensor_config import load_sensor_config, resolve_sensor_config
from thermal_sensors.temperature_frame import TemperatureFrameBuilder
from thermal_sensors.twin_source import TwinSource
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.scenario_runner import ScenarioRunner
from thermal_twin.sim.scenarios import make_timeline

ZERO_AXES = {"X": 0.0, "Y": 0.0, "Z": 0.0, "B": 0.0}


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


class EnvelopeSink(HeldCompensation):
    """The prediction held as the compensation a probe sees, and sent as axis offsets (at
    the axes' zero) through the bridge's own write path with the twin backend; every axis
    of every write recorded as the node would publish it."""

    def __init__(self, components, envelope: SafetyEnvelope):
        super().__init__(components)
        self.envelope = envelope
        self.core = BridgeCore(envelope, TwinBackend())
        self.rows = 0
        self.applied_um: dict[str, list[float]] = {}
        self.flags: dict[str, list[int]] = {}

    def apply(self, t_s, values, stds=None) -> None:
        super().apply(t_s, values, stds)
        self.rows += 1
        finite = {c: v for c, v in values.items() if math.isfinite(v)}
        update = self.core.update(t_s, finite or None, ZERO_AXES, fresh=bool(finite))
        for a in update.axes if update is not None else ():
            self.applied_um.setdefault(a.axis, [math.nan] * (self.rows - 1)).append(a.applied_um)
            self.flags.setdefault(a.axis, [0] * (self.rows - 1)).append(a.flags)


class InjectedProbe:
    """The probe of the core loop: true error minus the applied compensation; a cycle at or
    after a time in ``failures`` fails (once per time); ``outliers`` {time: um} adds that
    much to every linear component of the first measurement at or after the time."""

    def __init__(self, failures: Iterable[float], outliers: Mapping[float, float] | None):
        self.fail_at = sorted(float(x) for x in failures)
        self.outliers = dict(sorted((float(k), float(v)) for k, v in (outliers or {}).items()))
        self.errors_now: dict[str, float] = {}

    def __call__(self, t: float, applied: Mapping[str, float]) -> dict[str, float]:
        if self.fail_at and t >= self.fail_at[0]:
            self.fail_at.pop(0)
            raise ProbeFailed("injected: cycle failed")
        measured = {c: self.errors_now[c] - a for c, a in applied.items()}
        if self.outliers and t >= next(iter(self.outliers)):
            bad = self.outliers.pop(next(iter(self.outliers)))
            measured = {c: v + (0.0 if c in ANGULAR_COMPONENTS else bad) for c, v in measured.items()}
        return measured


def _temperatures(frame, status: dict[str, list[int]]) -> tuple[dict[str, float], list[str]]:
    """Model inputs from a frame: a sensor whose status is not OK is NaN (excluded, held)."""
    for sid, st in zip(frame.sensor_ids, frame.status):
        status[sid].append(int(st))
    return model_temperatures(frame.sensor_ids, frame.temperatures_degc, frame.status)


def run_core_loop(faults: Iterable[SensorFault] = (), hours: float = 48.0, seed: int = 0,
                  step_s: float = 300.0, max_rate_um_per_s: float = 0.5, abs_limit_um: float = 30.0,
                  probe_failures: Iterable[float] = (), probe_outliers: Mapping[float, float] | None = None,
                  progress: bool = False) -> LoopResult:
    """The loop of the module docstring. Probing: when the model says so, the true errors
    minus the compensation in effect are measured (:class:`InjectedProbe` for the faults);
    the prediction applied at that instant is made after learning from the probe."""
    machine = load_machine("nmv5000")
    runner = ScenarioRunner(machine, make_timeline(machine.name, "talc-178h-dry", hours=hours, seed=seed,
                                                   step_s=step_s), seed=seed)
    config = load_sensor_config(resolve_sensor_config("nmv5000"))
    source, builder = TwinSource(config), TemperatureFrameBuilder(config)
    talc_yaml = importlib.resources.files("talc_model") / "config" / "talc_nmv5000.yaml"
    model = make_model("talc", yaml.safe_load(talc_yaml.read_text()))
    comps = list(model.component_names)
    sink = EnvelopeSink(comps, SafetyEnvelope(EnvelopeConfig(
        abs_limit_um=abs_limit_um, max_rate_um_per_s=max_rate_um_per_s, max_step_s=600.0)))
    probe = InjectedProbe(probe_failures, probe_outliers)
    loop = ClosedLoop(model, sink, probe=probe, apply_after_probe=True)
    inj = FaultInjector(faults)
    rows_t, excluded_rows = [], []
    true = {c: [] for c in comps}
    pred = {c: [] for c in comps}
    status = {s: [] for s in config.sensor_ids}
    bar = tqdm(total=len(runner.timeline), unit="step", desc="core loop", leave=False) if progress else None
    while True:
        t = runner.t_s
        raw = inj.apply(t, runner.sensor_readings())
        source.accept(t, list(raw), list(raw.values()))
        temps, excl = _temperatures(builder.build(source.sample(t)), status)
        probe.errors_now = {k[:-3] if k.endswith("_um") else k: v for k, v in runner.errors().items()}
        step = loop.step(t, temps, {})
        excluded_rows.append(sorted(set(model.status(t).excluded_sensor_ids) | set(excl)))
        rows_t.append(t)
        for c in comps:
            true[c].append(probe.errors_now[c])
            pred[c].append(step.values.get(c, math.nan))
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
                      excluded_rows, sorted(sink.applied_um), {a: np.asarray(v) for a, v in sink.applied_um.items()},
                      {a: np.asarray(v) for a, v in sink.flags.items()}, st.probing_cycles,
                      st.failed_probing_cycles, st.no_good_phases, inj.injected, list(inj.counts))
