"""What a cell records of its errors: the probing results (sparse instants, noisy, measured on
a machine whose compensation was applied) as samples of the total error, and nothing else:
never the twin's ground-truth topic. No rclpy.

A bag: ``errors/measured`` (the model node's successful probing cycles) plus what the bridge
reported holding on ``offsets`` at that instant, turned into component space as the model node
does (talc_model.loop.applied_compensation): total = measured residual + applied. A recording
CSV: its error columns hold probe results as total errors, empty elsewhere.
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field

import numpy as np

from talc_model.loop.applied_compensation import BridgeCompensation
from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.recording import load_recording
from thermal_comp_common.probe_and_hold import table_5_4_noise
from thermal_comp_common.recording_csv import Recording

MEASURED_TOPIC = "errors/measured"
OFFSETS_TOPIC = "offsets"
#: fewest probes of one component a twin is learned from
MIN_PROBES = 4


class ProbeDataError(ValueError):
    """The probing results cannot be used; the message names the file, component or value."""


@dataclass
class ProbeSet:
    """Probes of the total error: instants (s), values per component (um, um/m) and their
    standard uncertainty per component."""

    time_s: np.ndarray
    values: dict[str, np.ndarray]
    noise: dict[str, float]
    source: str = ""
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.time_s = np.asarray(self.time_s, float)
        if self.time_s.ndim != 1 or not np.all(np.isfinite(self.time_s)):
            raise ProbeDataError(f"probes {self.source}: instants must be finite")
        if self.time_s.size > 1 and not np.all(np.diff(self.time_s) > 0):
            raise ProbeDataError(f"probes {self.source}: instants must increase")
        for c, v in self.values.items():
            v = self.values[c] = np.asarray(v, float)
            if v.shape != self.time_s.shape:
                raise ProbeDataError(f"probes {self.source}: component {c!r} has {v.size} values "
                                     f"for {self.time_s.size} instants")
            bad = np.isinf(v) | (np.abs(np.nan_to_num(v)) > 1e4)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ProbeDataError(f"probes {self.source}: component {c!r} at t = {self.time_s[i]:.0f} s "
                                     f"is {float(v[i])!r}, no measurement")
            s = self.noise.get(c)
            if s is None or not (math.isfinite(s) and s > 0):
                raise ProbeDataError(f"probes {self.source}: noise of {c!r} is {s!r}, must be > 0")

    def window(self, t0: float = -math.inf, t1: float = math.inf) -> "ProbeSet":
        """The probes with t0 <= t < t1."""
        keep = (self.time_s >= t0) & (self.time_s < t1)
        return ProbeSet(self.time_s[keep], {c: v[keep] for c, v in self.values.items()}, dict(self.noise),
                        self.source, list(self.notes))

    def count(self, c: str) -> int:
        return int(np.isfinite(self.values[c]).sum())


def strip_errors(rec: Recording) -> Recording:
    """The recording without any error column (what learning may see besides the probes)."""
    cols = {k: v for k, v in rec.columns.items() if k not in rec.errors}
    return Recording(rec.time_s, cols, source=rec.source, warnings=list(rec.warnings))


def cell_view(rec: Recording, machine) -> Recording:
    """What a cell records: no error column and no environment input a twin takes from a sensor
    (the true hall temperature)."""
    cell = strip_errors(rec)
    hidden = [n for n, s in machine.inputs.items() if s.from_sensor]
    return Recording(cell.time_s, {k: v for k, v in cell.columns.items() if k not in hidden}, source=rec.source)


def _component(col: str) -> str:
    return col[:-3] if col.endswith("_um") else col


def _applied_at(path: pathlib.Path, times: np.ndarray, components: list[str], b_pos: np.ndarray) -> np.ndarray:
    """What the CNC held at each probe instant, in component space (rows: instants)."""
    contents = read_bag(path)
    store = msg_definitions.typestore()
    msgs = sorted(((m.stamp_ns, m) for m in contents.messages if m.topic.endswith("/" + OFFSETS_TOPIC)
                   or m.topic == OFFSETS_TOPIC), key=lambda x: x[0])
    sink = BridgeCompensation(components, "offsets")
    out = np.zeros((times.size, len(components)))
    k = 0
    for i, t in enumerate(times):
        while k < len(msgs) and msgs[k][0] <= round(t * 1e9):
            msg = store.deserialize_cdr(msgs[k][1].data, msgs[k][1].type)
            offs = dict(zip(msg.axis_names, msg.applied_offsets_um)) \
                if len(msg.axis_names) == len(msg.applied_offsets_um) else None
            sink.on_offsets(msgs[k][0] / 1e9, msg.compensation_enabled, offs)
            k += 1
        sink.b_pos = float(b_pos[i]) if math.isfinite(b_pos[i]) else 0.0
        applied = sink.applied(float(t))
        out[i] = [applied.get(c, 0.0) for c in components]
    return out


def cell_recording(path, noise: dict[str, float] | None = None,
                   sample_period_s: float | None = None) -> tuple[Recording, ProbeSet]:
    """(temperatures and machine inputs, probes of the total error) from a cell's bag or a
    recording CSV (module docstring); ``noise``: the probes' uncertainty per component
    (default: the message's own, else Table 5.4); ``sample_period_s``: a CSV without a time column."""
    path = pathlib.Path(path)
    is_csv = path.is_file() and path.suffix.lower() == ".csv"
    rec = load_recording(path, sample_period_s=sample_period_s) if is_csv \
        else load_recording(path, errors_topic=MEASURED_TOPIC, sample_period_s=sample_period_s)
    cols = [c for c in rec.errors if np.isfinite(rec.columns[c]).any()]
    if not cols:
        raise ProbeDataError(f"{path}: no probing result ({'no error value' if is_csv else 'nothing on ' + MEASURED_TOPIC})")
    rows = np.flatnonzero(np.any([np.isfinite(rec.columns[c]) for c in cols], axis=0))
    times = rec.time_s[rows]
    comps = [_component(c) for c in cols]
    values = {comp: np.asarray(rec.columns[c], float)[rows] for comp, c in zip(comps, cols)}
    notes = []
    if not is_csv:
        b_pos = np.asarray(rec.columns.get("B_pos", np.zeros(len(rec))), float)[rows]
        applied = _applied_at(path, times, comps, b_pos)
        for j, c in enumerate(comps):
            values[c] = values[c] + applied[:, j]
        notes.append(f"total error = {MEASURED_TOPIC} + the offsets the bridge reported holding (component space)")
    probes = ProbeSet(times, values, dict(noise or table_5_4_noise(comps)), source=str(path), notes=notes)
    return strip_errors(rec), probes
