"""Real files for ``calibrate`` and ``diagnose``: Excel-style CSVs and a column mapping.

A CSV written by a spreadsheet or a data logger may start with a UTF-8 byte-order mark,
separate cells with ``;`` and write decimals with a comma; :func:`normalised_csv_text`
turns it into the project's recording CSV (read by the one reader,
``thermal_comp_common.recording_csv``). A mapping renames the file's columns to the twin's
names and scales them (``scale: -1`` flips a sign convention, ``0.001`` turns nm into um)::

    columns: {Zeit_s: time_s, Drehzahl: spindle_rpm, T_Lager_vorn: t5_c, Z_axial: ch3_um}
    scale: {ch3_um: -1}          # applied after renaming; the twin's sign is its YAML's

given as a YAML file (``--map-file``) or flags (``--map Zeit_s=time_s --map ch3_um*-1``).
:func:`name_mismatches` reports every column the twin does not know, and every twin
channel the file lacks, with the closest name (difflib).
"""
from __future__ import annotations

import csv
import difflib
import io
import pathlib
import re
from dataclasses import dataclass, field

import numpy as np
import yaml

from thermal_comp_common.bags.recording import load_recording
from thermal_comp_common.recording_csv import Recording, RecordingError, read_recording_csv, read_recording_text

_DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d*([eE][+-]?\d+)?$")


class MappingError(ValueError):
    """A column mapping is invalid; the message names the entry and value."""


@dataclass
class ColumnMapping:
    columns: dict[str, str] = field(default_factory=dict)     # file name -> twin name
    scale: dict[str, float] = field(default_factory=dict)     # twin name -> factor

    def __bool__(self) -> bool:
        return bool(self.columns or self.scale)


def parse_mapping(file: str | None = None, flags: list[str] | None = None) -> ColumnMapping:
    """A mapping from a YAML file and/or ``--map`` flags (``old=new`` renames, ``name*k``
    scales); flags win over the file."""
    m = ColumnMapping()
    if file:
        raw = yaml.safe_load(pathlib.Path(file).read_text(encoding="utf-8-sig")) or {}
        bad = [k for k in raw if k not in ("columns", "scale")]
        if bad:
            raise MappingError(f"{file}: {bad[0]!r} is not a key of a column mapping (allowed: columns, scale)")
        m.columns.update({str(k): str(v) for k, v in (raw.get("columns") or {}).items()})
        for k, v in (raw.get("scale") or {}).items():
            m.scale[str(k)] = _factor(v, f"{file}: scale.{k}")
    for f in flags or []:
        if "=" in f:
            old, new = (s.strip() for s in f.split("=", 1))
            if not old or not new:
                raise MappingError(f"--map {f!r}: expected OLD=NEW")
            m.columns[old] = new
        elif "*" in f:
            name, k = f.rsplit("*", 1)
            m.scale[name.strip()] = _factor(k, f"--map {f!r}")
        else:
            raise MappingError(f"--map {f!r}: expected OLD=NEW (rename) or NAME*FACTOR (scale)")
    return m


def _factor(v, where: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise MappingError(f"{where}: {v!r} is not a number") from None
    if not np.isfinite(x) or x == 0:
        raise MappingError(f"{where}: {v!r} must be a finite, non-zero factor")
    return x


def normalised_csv_text(text: str) -> tuple[str, list[str]]:
    """The recording-CSV text of an Excel-style CSV (BOM, ``;`` separator, decimal comma)
    and notes saying what was converted."""
    notes = []
    if text.startswith("\ufeff"):
        text = text[1:]
        notes.append("UTF-8 byte-order mark removed")
    head = text.split("\n", 1)[0]
    if head.count(";") > head.count(","):
        rows = list(csv.reader(io.StringIO(text), delimiter=";"))
        comma = any(_DECIMAL_COMMA.match(c.strip()) for r in rows[1:50] for c in r)
        if comma:
            rows = [rows[0]] + [[c.strip().replace(",", ".") if _DECIMAL_COMMA.match(c.strip()) else c
                                 for c in r] for r in rows[1:]]
        out = io.StringIO()
        csv.writer(out, lineterminator="\n").writerows(rows)
        text = out.getvalue()
        notes.append("';' separator" + (" and decimal comma" if comma else "") + " read as an Excel-style CSV")
    return text, notes


def _rename(rec: Recording, mapping: ColumnMapping) -> Recording:
    cols = {}
    for k, v in rec.columns.items():
        new = mapping.columns.get(k, k)
        if new in cols:
            raise MappingError(f"mapping: two columns become {new!r}")
        cols[new] = v
    for k, f in mapping.scale.items():
        if k not in cols:
            raise MappingError(f"mapping: scale.{k}: no such column after renaming"
                               + _closest(k, list(cols)))
        cols[k] = np.asarray(cols[k], dtype=float) * f
    return Recording(rec.time_s, cols, source=rec.source, warnings=list(rec.warnings))


def _closest(name: str, pool: list[str]) -> str:
    c = difflib.get_close_matches(name, pool, n=1, cutoff=0.4)
    return f" (closest: {c[0]})" if c else ""


def read_real_recording(path: str | pathlib.Path, mapping: ColumnMapping | None = None,
                        temperatures_topic: str = "temperatures",
                        errors_topic: str = "errors/ground_truth", sample_period_s: float | None = None) -> Recording:
    """A recording from a CSV (plain or Excel-style, with ``time_s`` or a column mapped to
    it, or without one: row index x ``sample_period_s``) or a bag, with the mapping applied;
    conversions are listed in ``warnings``."""
    path = pathlib.Path(path)
    mapping = mapping or ColumnMapping()
    if path.suffix.lower() != ".csv":
        return _rename(load_recording(path, temperatures_topic, errors_topic, sample_period_s), mapping)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    text, notes = normalised_csv_text(path.read_text(encoding="utf-8", errors="strict"))
    if mapping.columns:
        lines = text.split("\n", 1)
        header = next(csv.reader([lines[0]]))
        unknown = [k for k in mapping.columns if k not in [h.strip() for h in header]]
        if unknown:
            raise MappingError(f"mapping: column {unknown[0]!r} is not in {path.name}"
                               + _closest(unknown[0], [h.strip() for h in header]))
        header = [mapping.columns.get(h.strip(), h.strip()) for h in header]
        out = io.StringIO()
        csv.writer(out, lineterminator="\n").writerow(header)
        text = out.getvalue() + (lines[1] if len(lines) > 1 else "")
    if not notes and not mapping.columns:
        rec = read_recording_csv(path, sample_period_s=sample_period_s)
    else:   # parsed in memory: every error names the user's file
        rec = read_recording_text(text, str(path), sample_period_s=sample_period_s)
    rec = _rename(rec, ColumnMapping(scale=mapping.scale))
    rec.warnings = [f"{path.name}: {n}" for n in notes] + rec.warnings
    return rec


def name_mismatches(machine, rec: Recording) -> list[str]:
    """One line per recording column the twin does not use and per twin channel or input
    the recording lacks, each with the closest name on the other side."""
    twin_cols = ([machine.sensors[s].column for s in machine.sensors] + list(machine.errors)
                 + list(machine.inputs))
    rec_cols = list(rec.columns)
    out = []
    for c in rec_cols:
        if c not in twin_cols:
            out.append(f"recording column '{c}' is not a twin sensor, channel or input"
                       + _closest(c, twin_cols))
    for c in twin_cols:
        if c not in rec_cols and not (c in machine.inputs and machine.inputs[c].from_sensor
                                      and f"{machine.inputs[c].from_sensor}_c" in rec_cols):
            out.append(f"twin column '{c}' is not in the recording" + _closest(c, rec_cols))
    return out


def empty_columns(rec) -> list[str]:
    """Columns of the recording without a single finite value (named in reports, never dropped silently)."""
    return [c for c, v in rec.columns.items() if not np.isfinite(np.asarray(v, dtype=float)).any()]
