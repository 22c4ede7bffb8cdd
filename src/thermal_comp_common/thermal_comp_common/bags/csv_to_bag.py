"""Turning recording CSVs (``thermal_comp_common.recording_csv`` format) into rosbag2 bags of our types.

Per CSV row at time ``t`` (stamp = ``start_s + t``, simulated time):

- ``TemperatureArray`` on ``temperatures`` (or another topic): every ``<id>_c`` column is
  sensor ``<id>``; a failed reading (NaN or +-inf in the CSV) -> NaN with status FAILED, as
  the message contract says, else OK.
- ``ThermalErrors`` on ``errors/ground_truth`` (SOURCE_GROUND_TRUTH, the twin's CSV) or
  ``errors/measured`` (SOURCE_MEASURED): every error column, ``E_*`` keeping its name and
  ``<name>_um`` becoming ``<name>``; ``E_A0C E_B0C E_C0C`` in um/m, the rest in um;
  uncertainty NaN (unknown).
- ``MachineState`` on ``machine_state`` from the input columns it can represent, named as
  machine_sim names them (:func:`represented_inputs`); inputs it cannot represent (e.g. the
  twin's ``ambient_degc`` boundary) are listed in :attr:`ImportResult.unmapped`
  (``strict=True`` makes them an error).

Serialization uses the ``rosbags`` typestore built from the installed .msg files, so no
rclpy is needed. No rclpy import here; the command is :mod:`thermal_comp.bags.import_csv_cli`.
"""
from __future__ import annotations

import math
import os
import pathlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.bags.writer import DEFAULT_CHUNK_BYTES, BagWriter, TopicInfo, qos_dict
from thermal_comp_common.machine_state_fields import component_name, machine_state_fields
from thermal_comp_common.recording_csv import Recording, error_unit, read_recording_csv
from thermal_comp_common.sensor_readings import STATUS_FAILED, STATUS_OK

T_TEMPS = "thermal_comp_msgs/msg/TemperatureArray"
T_ERRORS = "thermal_comp_msgs/msg/ThermalErrors"
T_STATE = "thermal_comp_msgs/msg/MachineState"
SOURCE_MEASURED, SOURCE_GROUND_TRUTH = 0, 2
UNIT_UM, UNIT_UM_PER_M = 0, 1
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


def represented_inputs(columns: list[str]) -> tuple[list[str], list[str]]:
    """(input columns MachineState represents, the others) under the twin's naming rules.

    The mapping is :func:`thermal_comp_common.machine_state_fields.machine_state_fields`, the one
    machine_sim publishes with, so an imported bag looks like the live graph's.
    """
    empty = machine_state_fields({})
    used, unmapped = [], []
    for c in columns:
        (used if machine_state_fields({c: 1.0}) != empty else unmapped).append(c)
    return used, unmapped


def _topic(namespace: str, rel: str) -> str:
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{rel}"


def _checked_rows(rec: Recording, temperatures_topic: str, errors_as: str, start_s: float, every: int,
                  rows: tuple[int, int | None]) -> np.ndarray:
    """The row indices to import; a bad argument raises :class:`CsvImportError` naming it."""
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
    return np.arange(lo, hi, every)


def _machine_state(MachineState, header, inputs: dict[str, float]):
    """A MachineState message (rosbags type) from one row's input columns, as machine_sim fills it."""
    f = machine_state_fields(inputs)
    return MachineState(
        header=header,
        spindle_names=f["spindle_names"],
        spindle_speeds_rpm=np.asarray(f["spindle_speeds_rpm"], dtype=np.float64),
        rotary_axis_names=f["rotary_axis_names"],
        rotary_axis_speeds_rpm=np.asarray(f["rotary_axis_speeds_rpm"], dtype=np.float64),
        axis_names=[], axis_positions=np.zeros(0),
        coolant_on=f["coolant_on"], coolant_temperature_degc=f["coolant_temperature_degc"],
        door_open=f["door_open"],
        drive_names=f["drive_names"],
        drive_powers_w=np.asarray(f["drive_powers_w"], dtype=np.float64),
        machine_busy_probing=False)


def recording_to_bag(rec: Recording, out: str | os.PathLike, *, temperatures_topic: str = "temperatures",
                     errors_as: str = "ground_truth", error_model_kind: str | None = None,
                     namespace: str = "", start_s: float = 0.0, every: int = 1,
                     rows: tuple[int, int | None] = (0, None), strict: bool = False,
                     frame_id: str = "", chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                     progress: Callable[[int], None] | None = None) -> ImportResult:
    """Write ``rec`` as a bag folder ``out`` (see module doc). ``every`` keeps every n-th row."""
    idx = _checked_rows(rec, temperatures_topic, errors_as, start_s, every, rows)
    sensors = rec.names("sensor")
    errors = rec.names("error")
    state_cols, unmapped = represented_inputs(rec.names("input"))
    if unmapped and strict:
        raise CsvImportError(f"input column(s) {unmapped} cannot be represented in MachineState")
    has_state = bool(state_cols)
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
    comps = [component_name(c) for c in errors]
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
                msg = _machine_state(MachineState, header, {c: float(rec.columns[c][k]) for c in state_cols})
                bag.write(topics[0].name, t_ns, store.serialize_cdr(msg, T_STATE))
            if sensors:
                row = sens_mat[k].astype(np.float64)
                status = np.where(np.isfinite(row), STATUS_OK, STATUS_FAILED).astype(np.uint8)
                row[status == STATUS_FAILED] = np.nan     # the contract: a failed reading is NaN
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


__all__ = ["CsvImportError", "ImportResult", "csv_to_bag", "recording_to_bag", "represented_inputs"]
