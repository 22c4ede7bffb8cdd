"""Turning recording CSVs (``thermal_twin.recording_csv`` format) into rosbag2 bags of our types.

Per CSV row at time ``t`` (stamp = ``start_s + t``, simulated time):

- ``TemperatureArray`` on ``temperatures`` (or another topic): every ``<id>_c`` column is
  sensor ``<id>``; NaN -> status FAILED, else OK.
- ``ThermalErrors`` on ``errors/ground_truth`` (SOURCE_GROUND_TRUTH, the twin's CSV) or
  ``errors/measured`` (SOURCE_MEASURED): every error column, ``E_*`` keeping its name and
  ``<name>_um`` becoming ``<name>``; ``E_A0C E_B0C E_C0C`` in um/m, the rest in um;
  uncertainty NaN (unknown).
- ``MachineState`` on ``machine_state`` from the input columns it can represent (see
  :func:`machine_state_fields`); inputs it cannot represent are listed in
  :attr:`ImportResult.unmapped` (``strict=True`` makes them an error).

Serialization uses the ``rosbags`` typestore built from the installed .msg files, so no
rclpy is needed. No rclpy import here; the command is :mod:`thermal_comp.import_csv_cli`.
"""
from __future__ import annotations

import math
import os
import pathlib
import re
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from thermal_comp import msg_definitions
from thermal_comp.bag_recorder import DEFAULT_CHUNK_BYTES, BagWriter, TopicInfo, qos_dict
from thermal_twin.recording_csv import Recording, error_unit, read_recording_csv

T_TEMPS = "thermal_comp_msgs/msg/TemperatureArray"
T_ERRORS = "thermal_comp_msgs/msg/ThermalErrors"
T_STATE = "thermal_comp_msgs/msg/MachineState"
SOURCE_MEASURED, SOURCE_GROUND_TRUTH = 0, 2
UNIT_UM, UNIT_UM_PER_M = 0, 1
STATUS_OK, STATUS_FAILED = 0, 3
ERROR_TOPICS = {"ground_truth": ("errors/ground_truth", SOURCE_GROUND_TRUTH),
                "measured": ("errors/measured", SOURCE_MEASURED)}


class CsvImportError(ValueError):
    """Bad import request; the message names the option / column and value."""


@dataclass
class ImportResult:
    bag: pathlib.Path
    rows: int
    messages: dict[str, int]
    unmapped: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def _stem(name: str, suffixes: tuple[str, ...]) -> str:
    for s in suffixes:
        if name.endswith(s):
            return name[: -len(s)]
    return name


def _axis_label(stem: str) -> str:
    return stem.upper() if len(stem) <= 2 else stem


def machine_state_fields(columns: list[str]) -> tuple[dict[str, list[tuple[str, str]]], list[str]]:
    """Map input columns to MachineState fields.

    Returns ({field group: [(name in the message, column)]}, unmapped columns). Rules:
    ``*spindle*_rpm`` -> spindle (name = column stem), other ``<x>_speed_rpm`` / ``<x>_rpm``
    -> rotary axis ``X``; ``coolant_on``, ``door_open``, ``machine_busy_probing`` /
    ``probing`` -> booleans; ``coolant_temp_degc`` / ``coolant_temperature_degc`` -> the
    coolant supply temperature; ``<x>_power_w`` / ``<x>_w`` -> drive ``X`` power;
    ``pos_<x>`` / ``<x>_pos_mm`` / ``<x>_pos_deg`` -> axis position.
    """
    groups: dict[str, list[tuple[str, str]]] = {k: [] for k in (
        "spindle", "rotary", "axis", "drive", "coolant_on", "coolant_temp", "door_open", "probing")}
    unmapped = []
    for c in columns:
        if c.endswith("_rpm") and "spindle" in c:
            groups["spindle"].append((_stem(c, ("_speed_rpm", "_rpm")), c))
        elif c.endswith("_rpm"):
            groups["rotary"].append((_axis_label(_stem(c, ("_speed_rpm", "_rpm"))), c))
        elif c == "coolant_on":
            groups["coolant_on"].append((c, c))
        elif c in ("coolant_temp_degc", "coolant_temperature_degc"):
            groups["coolant_temp"].append((c, c))
        elif c == "door_open":
            groups["door_open"].append((c, c))
        elif c in ("machine_busy_probing", "probing"):
            groups["probing"].append((c, c))
        elif c.endswith("_w"):
            groups["drive"].append((_axis_label(_stem(c, ("_power_w", "_w"))), c))
        elif re.fullmatch(r"pos_\w+", c) or re.fullmatch(r"\w+_pos_(mm|deg)", c):
            stem = c[4:] if c.startswith("pos_") else c.rsplit("_pos_", 1)[0]
            groups["axis"].append((_axis_label(stem), c))
        else:
            unmapped.append(c)
    return groups, unmapped


def error_component(column: str) -> str:
    """Component name of an error column: 'E_X0C' stays, 'ch1_um' -> 'ch1'."""
    return column[:-3] if column.endswith("_um") else column


def _topic(namespace: str, rel: str) -> str:
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{rel}"


def recording_to_bag(rec: Recording, out: str | os.PathLike, *, temperatures_topic: str = "temperatures",
                     errors_as: str = "ground_truth", error_model_kind: str | None = None,
                     namespace: str = "", start_s: float = 0.0, every: int = 1,
                     rows: tuple[int, int | None] = (0, None), strict: bool = False,
                     frame_id: str = "", chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                     progress: Callable[[int], None] | None = None) -> ImportResult:
    """Write ``rec`` as a bag folder ``out`` (see module doc). ``every`` keeps every n-th row."""
    if errors_as not in ERROR_TOPICS:
        raise CsvImportError(f"errors_as: {errors_as!r} is not one of {list(ERROR_TOPICS)}")
    if every < 1:
        raise CsvImportError(f"every: {every!r} must be >= 1")
    if not math.isfinite(start_s) or start_s < 0:
        raise CsvImportError(f"start_s: {start_s!r} must be a finite time >= 0")
    if not temperatures_topic or temperatures_topic.startswith("/"):
        raise CsvImportError(f"temperatures_topic: {temperatures_topic!r} must be a relative name")
    lo, hi = rows
    hi = len(rec) if hi is None else hi
    if not 0 <= lo < hi <= len(rec):
        raise CsvImportError(f"rows: {lo}:{hi} is not a non-empty range of the {len(rec)} rows")
    idx = np.arange(lo, hi, every)
    sensors = rec.names("sensor")
    errors = rec.names("error")
    groups, unmapped = machine_state_fields(rec.names("input"))
    if unmapped and strict:
        raise CsvImportError(f"input column(s) {unmapped} cannot be represented in MachineState")
    has_state = any(groups.values())
    store = msg_definitions.typestore()
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    TemperatureArray = store.types[T_TEMPS]
    ThermalErrors = store.types[T_ERRORS]
    MachineState = store.types[T_STATE]
    err_topic, source = ERROR_TOPICS[errors_as]
    kind = error_model_kind or ("twin" if source == SOURCE_GROUND_TRUTH else "recording")
    topics = []
    if has_state:
        topics.append(TopicInfo(_topic(namespace, "machine_state"), T_STATE, [qos_dict(depth=50)]))
    if sensors:
        topics.append(TopicInfo(_topic(namespace, temperatures_topic), T_TEMPS, [qos_dict(depth=50)]))
    if errors:
        topics.append(TopicInfo(_topic(namespace, err_topic), T_ERRORS, [qos_dict(depth=100)]))
    if not topics:
        raise CsvImportError(f"{rec.source}: no sensor, error or machine-state column to import")
    names = [c[:-2] for c in sensors]
    comps = [error_component(c) for c in errors]
    units = np.array([UNIT_UM_PER_M if error_unit(c) == "um/m" else UNIT_UM for c in errors], dtype=np.uint8)
    sens_mat = np.column_stack([rec.columns[c] for c in sensors]) if sensors else None
    err_mat = np.column_stack([rec.columns[c] for c in errors]) if errors else None
    counts = {t.name: 0 for t in topics}
    with BagWriter(out, topics, chunk_bytes=chunk_bytes, custom_data={"imported_from": str(rec.source)}) as bag:
        for done, k in enumerate(idx):
            t_ns = int(round((start_s + float(rec.time_s[k])) * 1e9))
            sec, nsec = divmod(t_ns, 1_000_000_000)
            header = Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id)
            if has_state:
                def vals(group):
                    return np.array([float(rec.columns[c][k]) for _, c in groups[group]], dtype=np.float64)

                def flag(group):
                    return bool(groups[group]) and float(rec.columns[groups[group][0][1]][k]) > 0.5

                coolant_t = (float(rec.columns[groups["coolant_temp"][0][1]][k])
                             if groups["coolant_temp"] else math.nan)
                msg = MachineState(
                    header=header,
                    spindle_names=[n for n, _ in groups["spindle"]], spindle_speeds_rpm=vals("spindle"),
                    rotary_axis_names=[n for n, _ in groups["rotary"]], rotary_axis_speeds_rpm=vals("rotary"),
                    axis_names=[n for n, _ in groups["axis"]], axis_positions=vals("axis"),
                    coolant_on=flag("coolant_on"), coolant_temperature_degc=coolant_t,
                    door_open=flag("door_open"),
                    drive_names=[n for n, _ in groups["drive"]], drive_powers_w=vals("drive"),
                    machine_busy_probing=flag("probing"))
                bag.write(topics[0].name, t_ns, store.serialize_cdr(msg, T_STATE))
            if sensors:
                row = sens_mat[k].astype(np.float64)
                status = np.where(np.isfinite(row), STATUS_OK, STATUS_FAILED).astype(np.uint8)
                msg = TemperatureArray(header=header, sensor_ids=names, temperatures_degc=row, status=status)
                bag.write(_topic(namespace, temperatures_topic), t_ns, store.serialize_cdr(msg, T_TEMPS))
            if errors:
                row = err_mat[k].astype(np.float64)
                msg = ThermalErrors(header=header, source=source, model_kind=kind, component_names=comps,
                                    values=row, units=units,
                                    uncertainties=np.full(len(comps), np.nan))
                bag.write(_topic(namespace, err_topic), t_ns, store.serialize_cdr(msg, T_ERRORS))
            if progress is not None and (done + 1) % 1000 == 0:
                progress(1000)
        counts = dict(bag.counts)
    if progress is not None:
        progress(len(idx) % 1000)
    return ImportResult(pathlib.Path(out), len(idx), counts, unmapped, list(rec.warnings))


def csv_to_bag(csv_path: str | os.PathLike, out: str | os.PathLike, **kwargs) -> ImportResult:
    """Read a recording CSV and write it as a bag (keyword arguments of :func:`recording_to_bag`)."""
    return recording_to_bag(read_recording_csv(csv_path), out, **kwargs)


__all__ = ["CsvImportError", "ImportResult", "csv_to_bag", "error_component",
           "machine_state_fields", "recording_to_bag"]
