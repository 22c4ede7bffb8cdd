"""Mapping our messages to rerun entities (used for bags and for live topics alike).

Entity paths (``<ns>/`` is the cell namespace of the topic, empty for the root namespace):

==================================================  ===========================================
``<ns>/temperatures/<sensor>``                      calibrated temperature, degC (``temperatures``)
``<ns>/twin_sensors/<sensor>``                      raw twin readings (``twin/sensor_readings``)
``<ns>/errors/<component>/ground_truth``            twin's true error (magenta line)
``<ns>/errors/<component>/predicted``               model prediction (blue line) with
``<ns>/errors/<component>/predicted_upper_2sigma``  the uncertainty band: prediction +- 2 u
``<ns>/errors/<component>/predicted_lower_2sigma``  (k = 2, light blue lines)
``<ns>/errors/<component>/measured``                probing result (orange diamond markers)
``<ns>/offsets/<axis>/commanded`` / ``applied``     CNC offsets, um
``<ns>/model/phase`` ...                            phase (0 calibration, 1 compensation,
                                                    2 no-good), max uncertainty, Q_prod, cycles
``<ns>/machine/...``                                spindle / rotary speeds, drive powers, coolant,
                                                    door, probing flag
``<ns>/machine/sensors``                            3D sensor layout coloured by temperature
``<ns>/events``                                     text log: probing, phase changes, limits, failed sensors
``diagnostics/<node>/<status>``                     ``/diagnostics`` (diagnostic_msgs/DiagnosticArray):
                                                    a text line when a status's level or message
                                                    changes, and ``.../level`` (0 OK .. 3 stale)
``rosout/<node>``                                   ``/rosout`` (rcl_interfaces/Log) lines, with level
==================================================  ===========================================

Time is the message stamp on the timeline ``sim_time`` (seconds since 0 in simulation).
``/rosout`` and ``/diagnostics`` are health records stamped by their node's clock, which is the
wall clock for every log line: a wall-clock stamp goes on its own timeline ``wall_time`` and
never on ``sim_time``; there the record sits at the simulated instant it arrived (in a bag:
the newest data stamp received before it; live: the newest data stamp logged so far). A
diagnostics stamp that is not a wall-clock date is on the simulated clock and kept as is.
No ``log_time``: the sinks turn rerun's automatic wall-clock timeline off.
Live topics are logged message by message; a whole bag is converted ``columnar``: scalars
and text lines are gathered per entity and sent with ``rr.send_columns`` in one call each
(:meth:`RerunLogger.send_columns`), which is what makes the conversion fast.
Messages are duck-typed: rclpy messages and ``rosbags`` deserialized ones have the same
fields. No rclpy import here.

Sensor layout in 3D: a YAML file with ``sensors: {<id>: {position_mm: [x, y, z]}}`` or the
name of a twin preset (the presets carry ``position_mm``: a schematic layout of the virtual
machine). Without one, the first preset whose positioned sensors include every sensor id
seen is used; failing that the sensors are drawn on a labelled *schematic* ring (1 m
radius, in id order), which says nothing about where they are on the machine. The view
states which layout it shows (``machine/sensors/layout_note``).
"""
from __future__ import annotations

import math
import os
import pathlib
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np
import rerun as rr
import yaml

from thermal_comp_common.frames import FrameError, frame_tree, positions_in_root, sensor_frame

TIMELINE = "sim_time"
WALL_TIMELINE = "wall_time"
#: stamps at or after this many seconds since the epoch (2001-09-09) are wall-clock dates
WALL_CLOCK_MIN_S = 1e9
COLOURS = {
    "ground_truth": (230, 30, 230),
    "predicted": (30, 110, 240),
    "band": (150, 190, 250),
    "measured": (255, 140, 0),
    "commanded": (120, 120, 120),
    "applied": (20, 160, 60),
}
PHASES = {0: "calibration", 1: "compensation", 2: "no-good"}
SOURCES = {0: "measured", 1: "predicted", 2: "ground_truth"}
STATUS = {0: "ok", 1: "stale", 2: "out of range", 3: "failed"}
#: relative topic -> entity sub-tree for TemperatureArray topics
TEMPERATURE_TREES = {"temperatures": "temperatures", "twin/sensor_readings": "twin_sensors"}
#: diagnostic_msgs/DiagnosticStatus level -> rerun text-log level
DIAGNOSTIC_LEVELS = {0: "INFO", 1: "WARN", 2: "ERROR", 3: "WARN"}
DIAGNOSTIC_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
#: rcl_interfaces/Log level -> rerun text-log level
ROSOUT_LEVELS = {10: "DEBUG", 20: "INFO", 30: "WARN", 40: "ERROR", 50: "CRITICAL"}
#: types from outside thermal_comp_msgs that are drawn: type -> handler name
FOREIGN_TYPES = {"diagnostic_msgs/msg/DiagnosticArray": "_log_DiagnosticArray",
                 "rcl_interfaces/msg/Log": "_log_Log"}
KNOWN_RELATIVE = ("twin/sensor_readings", "temperatures", "machine_state", "errors/ground_truth",
                  "errors/predicted", "errors/measured", "model_status", "offsets", "sim_sync")


class LayoutError(ValueError):
    """A sensor-layout file is malformed; the message names the key and value."""


@dataclass
class SensorLayout:
    positions_m: dict[str, tuple[float, float, float]]
    schematic: bool
    source: str


def load_layout(path: str | os.PathLike) -> SensorLayout:
    """Sensor positions from ``sensors: {id: {position_mm: [x, y, z]}}`` (mm -> m)."""
    path = pathlib.Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise LayoutError(f"{path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise LayoutError(f"{path}: not valid YAML: {exc}") from None
    sensors = data.get("sensors") if isinstance(data, dict) else None
    if not isinstance(sensors, dict):
        raise LayoutError(f"{path}: key 'sensors' missing or not a mapping")
    try:   # the frames static_frames publishes on /tf_static, so TF and the 3D view agree
        origins = positions_in_root(frame_tree({"nodes": data.get("nodes") or {}, "sensors": sensors}))
    except FrameError as exc:
        raise LayoutError(f"{path}: {exc}") from None
    pos = {str(sid): origins[sensor_frame(str(sid))] for sid in sensors if sensor_frame(str(sid)) in origins}
    if not pos:
        raise LayoutError(f"{path}: no sensor has a 'position_mm'")
    return SensorLayout(pos, schematic=False, source=str(path))


def resolve_layout(arg: str) -> SensorLayout:
    """A layout file, or a twin preset name (``nmv5000``, ``swiss-lathe`` ...)."""
    if pathlib.Path(arg).is_file():
        return load_layout(arg)
    from thermal_twin.machine.presets import preset_names, preset_path  # optional: the twin only for preset names
    try:
        layout = load_layout(preset_path(arg))
    except Exception as exc:
        if isinstance(exc, LayoutError):
            raise
        raise LayoutError(f"layout {arg!r}: neither a file nor a twin preset "
                          f"(presets: {', '.join(preset_names())})") from None
    layout.source = f"twin preset {arg} (schematic layout of the virtual machine, not measured positions)"
    return layout


def preset_layout_for(sensor_ids: Iterable[str]) -> SensorLayout | None:
    """The first twin preset (by name) whose positioned sensors include all ``sensor_ids``."""
    ids = set(sensor_ids)
    try:
        from thermal_twin.machine.presets import preset_names  # optional: the twin only for preset names
    except ImportError:   # the twin is optional for viewing
        return None
    for name in preset_names():
        try:
            layout = resolve_layout(name)
        except LayoutError:
            continue
        if ids and ids <= set(layout.positions_m):
            return layout
    return None


def schematic_layout(sensor_ids: Iterable[str]) -> SensorLayout:
    ids = sorted(set(sensor_ids))
    n = max(len(ids), 1)
    pos = {sid: (math.cos(2 * math.pi * i / n), math.sin(2 * math.pi * i / n), 0.0)
           for i, sid in enumerate(ids)}
    return SensorLayout(pos, schematic=True, source="schematic ring (positions unknown)")


def split_topic(topic: str) -> tuple[str, str]:
    """'/cell1/errors/predicted' -> ('cell1', 'errors/predicted'); unknown -> ('', topic)."""
    t = topic.strip("/")
    for rel in KNOWN_RELATIVE:
        if t == rel:
            return "", rel
        if t.endswith("/" + rel):
            return t[: -len(rel) - 1], rel
    return "", t


def path_part(name: str) -> str:
    """One entity-path part (escaped; "_" for an empty name)."""
    return rr.escape_entity_path_part(str(name)) if name else "_"


def _blend(t: float) -> tuple[int, int, int]:
    """Blue (cold) -> red (warm) for t in [0, 1]."""
    t = min(max(t, 0.0), 1.0)
    return (int(40 + 215 * t), int(90 + 60 * (1 - abs(2 * t - 1))), int(255 - 215 * t))


class RerunLogger:
    """Logs messages to a rerun recording stream (see the module doc for the entities)."""

    def __init__(self, recording: rr.RecordingStream, layout: SensorLayout | None = None,
                 columnar: bool = False):
        self.rec = recording
        self.layout = layout
        self.columnar = columnar
        self._t_s: float | None = 0.0        # sim_time of the message being logged (None: none)
        self._wall_s: float | None = None    # wall_time of a health record (None: none)
        self._data_t_s: float | None = None  # newest data stamp logged so far
        self._rec_t: tuple | None = None     # (sim, wall) last set on the recording
        #: columnar: entity -> (sim times, wall times, values); NaN where a row has no such time
        self._scalars: dict[str, tuple[list[float], list[float], list[float]]] = {}
        self._texts: dict[str, tuple[list[float], list[float], list[str], list[str]]] = {}
        #: columnar: 3D layout entity -> (sim times, points, colours, labels), a list item per row
        self._points: dict[str, tuple[list[float], list, list, list]] = {}
        self._styled: set[str] = set()
        self._last_phase: dict[str, int] = {}
        self._last_status: dict[str, int] = {}
        self._last_diagnostic: dict[str, tuple[int, str]] = {}
        self._probing: dict[str, bool] = {}
        self._t_range: list[float] = [math.inf, -math.inf]
        self._unknown: set[str] = set()
        self._calibrated: set[str] = set()
        self._layout_noted: set[str] = set()
        self.counts: dict[str, int] = {}

    # ----------------------------------------------------------------------------------
    def _style(self, path: str, kind: str, name: str) -> None:
        if path in self._styled:
            return
        self._styled.add(path)
        c = COLOURS.get(kind)
        if kind == "measured":
            self.rec.log(path, rr.SeriesPoints(colors=[c], markers=["Diamond"], marker_sizes=[4.0],
                                               names=[name]), static=True)
        elif c is not None:
            width = 1.0 if kind == "band" else 2.0
            self.rec.log(path, rr.SeriesLines(colors=[c], widths=[width], names=[name]), static=True)

    def _timed(self) -> rr.RecordingStream:
        """The recording with its times set to the current message's (set only when they changed);
        a timeline the message has no instant on is disabled for it."""
        if self._rec_t != (self._t_s, self._wall_s):
            for name, t, kind in ((TIMELINE, self._t_s, "duration"), (WALL_TIMELINE, self._wall_s, "timestamp")):
                if t is None:
                    self.rec.disable_timeline(name)
                else:
                    self.rec.set_time(name, **{kind: t})
            self._rec_t = (self._t_s, self._wall_s)
        return self.rec

    def _row_times(self) -> tuple[float, float]:
        nan = math.nan
        return (nan if self._t_s is None else self._t_s), (nan if self._wall_s is None else self._wall_s)

    def _scalar(self, path: str, value: float, kind: str | None = None, name: str = "") -> None:
        if value is None or not math.isfinite(float(value)):
            return
        if kind:
            self._style(path, kind, name or path.rsplit("/", 1)[-1])
        if self.columnar:
            times, walls, values = self._scalars.setdefault(path, ([], [], []))
            t, w = self._row_times()
            times.append(t)
            walls.append(w)
            values.append(float(value))
        else:
            self._timed().log(path, rr.Scalars([float(value)]))

    def _event(self, ns: str, text: str, level: str = "INFO") -> None:
        self._text(f"{ns}events", text, level)

    def _text(self, path: str, text: str, level: str) -> None:
        if self.columnar:
            times, walls, texts, levels = self._texts.setdefault(path, ([], [], [], []))
            t, w = self._row_times()
            times.append(t)
            walls.append(w)
            texts.append(text)
            levels.append(level)
        else:
            self._timed().log(path, rr.TextLog(text, level=level))

    def send_columns(self) -> int:
        """Columnar: send what was gathered (one ``rr.send_columns`` per entity) and forget it;
        the number of rows sent. Nothing to do when logging message by message."""
        rows = 0
        for path, (times, walls, values) in self._scalars.items():
            v = np.asarray(values)
            rows += self._send(path, times, walls, lambda sel, v=v: rr.Scalars.columns(scalars=v[sel]))
        for path, (times, walls, texts, levels) in self._texts.items():
            tx, lv = np.asarray(texts, dtype=object), np.asarray(levels, dtype=object)
            rows += self._send(path, times, walls, lambda sel, tx=tx, lv=lv: rr.TextLog.columns(
                text=list(tx[sel]), level=list(lv[sel])))
        for path, (times, pts, cols, labels) in self._points.items():
            n = sum(len(x) for x in pts)
            self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(times))],
                                  columns=rr.Points3D.columns(
                                      positions=np.concatenate(pts), colors=np.concatenate(cols),
                                      labels=[x for row in labels for x in row], radii=np.full(n, 0.04),
                                  ).partition([len(x) for x in pts]))
            rows += len(times)
        self._scalars, self._texts, self._points = {}, {}, {}
        return rows

    def _send(self, path: str, times: list[float], walls: list[float], columns) -> int:
        """One ``send_columns`` per set of timelines the rows have (data rows: sim_time only)."""
        t, w = np.asarray(times, dtype=float), np.asarray(walls, dtype=float)
        has_t, has_w = ~np.isnan(t), ~np.isnan(w)
        rows = 0
        for want_t, want_w in ((True, False), (True, True), (False, True)):
            sel = (has_t == want_t) & (has_w == want_w)
            if not sel.any():
                continue
            indexes = ([rr.TimeColumn(TIMELINE, duration=t[sel])] if want_t else []) + \
                      ([rr.TimeColumn(WALL_TIMELINE, timestamp=w[sel])] if want_w else [])
            self.rec.send_columns(path, indexes=indexes, columns=columns(sel))
            rows += int(sel.sum())
        return rows

    # ----------------------------------------------------------------------------------
    def log(self, topic: str, type_name: str, msg: Any, t_ns: int, arrival_ns: int | None = None) -> None:
        """Log one message of ``topic`` (type 'pkg/msg/Type') stamped ``t_ns``. A health record
        (``/rosout``, ``/diagnostics``) goes on ``sim_time`` at ``arrival_ns``, the simulated
        instant it arrived (None: the newest data stamp logged so far), see the module doc."""
        self._set_times(type_name, t_ns * 1e-9, None if arrival_ns is None else arrival_ns * 1e-9)
        ns, rel = split_topic(topic)
        prefix = f"{ns}/" if ns else ""
        short = type_name.rsplit("/", 1)[-1]
        handler = (getattr(self, FOREIGN_TYPES[type_name]) if type_name in FOREIGN_TYPES else
                   getattr(self, f"_log_{short}", None) if type_name.startswith("thermal_comp_msgs/") else None)
        if handler is None:
            if topic not in self._unknown:
                self._unknown.add(topic)
                self._event(prefix, f"topic {topic} ({type_name}) is not visualised", "DEBUG")
            return
        handler(prefix, rel, msg)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _set_times(self, type_name: str, stamp_s: float, arrival_s: float | None) -> None:
        if type_name not in FOREIGN_TYPES:       # data: its stamp is simulated time
            self._t_s, self._wall_s = stamp_s, None
            self._data_t_s = stamp_s if self._data_t_s is None else max(self._data_t_s, stamp_s)
            return
        # log lines are always stamped by the wall clock; diagnostics by their node's clock
        wall = type_name == "rcl_interfaces/msg/Log" or stamp_s >= WALL_CLOCK_MIN_S
        self._wall_s = stamp_s if wall else None
        self._t_s = (arrival_s if arrival_s is not None else self._data_t_s) if wall else stamp_s

    def _log_TemperatureArray(self, p: str, rel: str, m) -> None:
        tree = TEMPERATURE_TREES.get(rel, path_part(rel))
        values = [float(v) for v in m.temperatures_degc]
        for sid, v, st in zip(m.sensor_ids, values, m.status):
            self._scalar(f"{p}{tree}/{path_part(sid)}", v)
            key = f"{p}{tree}/{sid}"
            if self._last_status.get(key, 0) != int(st):
                self._event(p, f"sensor {sid} ({rel}): {STATUS.get(int(st), st)}",
                            "WARN" if int(st) else "INFO")
                self._last_status[key] = int(st)
        if rel == "temperatures":
            self._calibrated.add(p)
        if rel == "temperatures" or p not in self._calibrated:   # raw readings until calibrated ones come
            self._log_layout(p, list(m.sensor_ids), values)

    def _log_layout(self, p: str, ids: list[str], values: list[float]) -> None:
        if self.layout is None:
            self.layout = preset_layout_for(ids) or schematic_layout(ids)
        if p not in self._layout_noted:
            self._layout_noted.add(p)
            self.rec.log(f"{p}machine/sensors/layout_note",
                         rr.TextDocument(f"Sensor layout: {self.layout.source}."), static=True)
        finite = [v for v in values if math.isfinite(v)]
        if finite:
            self._t_range = [min(self._t_range[0], min(finite)), max(self._t_range[1], max(finite))]
        lo, hi = self._t_range
        span = hi - lo if hi > lo else 1.0
        pts, cols, labels = [], [], []
        for sid, v in zip(ids, values):
            xyz = self.layout.positions_m.get(sid)
            if xyz is None:
                continue
            pts.append(xyz)
            cols.append(_blend((v - lo) / span) if math.isfinite(v) else (128, 128, 128))
            labels.append(f"{sid} {v:.2f} C" if math.isfinite(v) else f"{sid} failed")
        if pts and self.columnar:      # data messages: always on sim_time
            times, rows, colours, texts = self._points.setdefault(f"{p}machine/sensors", ([], [], [], []))
            times.append(self._t_s)
            rows.append(np.asarray(pts, dtype=np.float32))
            colours.append(np.asarray(cols, dtype=np.uint8))
            texts.append(labels)
        elif pts:
            self._timed().log(f"{p}machine/sensors", rr.Points3D(np.asarray(pts), colors=cols, labels=labels,
                                                           radii=0.04))

    def _log_ThermalErrors(self, p: str, rel: str, m) -> None:
        kind = SOURCES.get(int(m.source), f"source_{int(m.source)}")
        us = list(m.uncertainties) if len(m.uncertainties) == len(m.values) else [math.nan] * len(m.values)
        for comp, v, u in zip(m.component_names, m.values, us):
            base = f"{p}errors/{path_part(comp)}"
            self._scalar(f"{base}/{kind}", float(v), kind, f"{comp} {kind}")
            if kind == "predicted" and math.isfinite(float(u)):
                self._scalar(f"{base}/predicted_upper_2sigma", float(v) + 2 * float(u), "band", f"{comp} +2u")
                self._scalar(f"{base}/predicted_lower_2sigma", float(v) - 2 * float(u), "band", f"{comp} -2u")
        if kind == "measured":
            parts = ", ".join(f"{c}={float(v):.2f}" for c, v in zip(m.component_names, m.values))
            self._event(p, f"probing result ({m.model_kind}): {parts}")

    def _log_AxisOffsets(self, p: str, rel: str, m) -> None:
        for i, axis in enumerate(m.axis_names):
            base = f"{p}offsets/{path_part(axis)}"
            if i < len(m.commanded_offsets_um):
                self._scalar(f"{base}/commanded", float(m.commanded_offsets_um[i]), "commanded",
                             f"{axis} commanded")
            if i < len(m.applied_offsets_um):
                self._scalar(f"{base}/applied", float(m.applied_offsets_um[i]), "applied", f"{axis} applied")
            if i < len(m.limits_hit) and int(m.limits_hit[i]):
                self._event(p, f"offset {axis}: limit flags {int(m.limits_hit[i])}", "WARN")
        self._scalar(f"{p}offsets/compensation_enabled", 1.0 if m.compensation_enabled else 0.0)

    def _log_ModelStatus(self, p: str, rel: str, m) -> None:
        phase = int(m.phase)
        self._scalar(f"{p}model/phase", phase)
        self._scalar(f"{p}model/max_uncertainty", float(m.max_uncertainty))
        self._scalar(f"{p}model/q_prod_pct", float(m.q_prod_pct))
        self._scalar(f"{p}model/probing_cycles", int(m.probing_cycles))
        self._scalar(f"{p}model/parameter_updates", int(m.parameter_updates))
        if self._last_phase.get(p) != phase:
            self._event(p, f"model {m.model_kind}: phase {PHASES.get(phase, phase)}"
                        + (f" - {m.message}" if m.message else ""), "WARN" if phase == 2 else "INFO")
            self._last_phase[p] = phase

    def _log_MachineState(self, p: str, rel: str, m) -> None:
        for name, v in zip(m.spindle_names, m.spindle_speeds_rpm):
            self._scalar(f"{p}machine/spindle/{path_part(name)}_rpm", float(v))
        for name, v in zip(m.rotary_axis_names, m.rotary_axis_speeds_rpm):
            self._scalar(f"{p}machine/rotary/{path_part(name)}_rpm", float(v))
        for name, v in zip(m.drive_names, m.drive_powers_w):
            self._scalar(f"{p}machine/drive_power/{path_part(name)}_w", float(v))
        for name, v in zip(m.axis_names, m.axis_positions):
            self._scalar(f"{p}machine/axis/{path_part(name)}", float(v))
        self._scalar(f"{p}machine/coolant_on", 1.0 if m.coolant_on else 0.0)
        self._scalar(f"{p}machine/coolant_temperature_degc", float(m.coolant_temperature_degc))
        self._scalar(f"{p}machine/door_open", 1.0 if m.door_open else 0.0)
        busy = bool(m.machine_busy_probing)
        self._scalar(f"{p}machine/busy_probing", 1.0 if busy else 0.0)
        if busy != self._probing.get(p, False):
            self._event(p, "probing cycle started" if busy else "probing cycle finished")
            self._probing[p] = busy

    def _log_DiagnosticArray(self, p: str, rel: str, m) -> None:
        """Each status: its level as a scalar, a text line when level or message changed."""
        for st in m.status:
            node, _, name = str(st.name).rpartition(": ")
            name = name.replace(" ", "_")     # 'sensor spindle' -> sensor_spindle (no escaped spaces)
            path = f"{p}diagnostics/{path_part(node) + '/' if node else ''}{path_part(name)}"
            level = int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)
            self._scalar(f"{path}/level", float(level))
            if self._last_diagnostic.get(path) != (level, st.message):
                self._last_diagnostic[path] = (level, st.message)
                values = ", ".join(f"{kv.key}={kv.value}" for kv in st.values)
                self._text(path, f"{DIAGNOSTIC_NAMES.get(level, level)} {st.name}: {st.message}"
                           + (f" ({values})" if values else ""), DIAGNOSTIC_LEVELS.get(level, "WARN"))

    def _log_Log(self, p: str, rel: str, m) -> None:
        """One /rosout line under the node that wrote it."""
        node = str(m.name).replace(".", "/").strip("/")
        self._text(f"{p}rosout/{'/'.join(path_part(x) for x in node.split('/')) if node else '_'}",
                   f"[{m.name}] {m.msg}", ROSOUT_LEVELS.get(int(m.level), "INFO"))

    def _log_SimSync(self, p: str, rel: str, m) -> None:
        """Lock-step handshakes carry no measurement; counted, not drawn."""
