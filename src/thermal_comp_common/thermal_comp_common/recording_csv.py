"""The recording CSV format shared by the twin, replay, import and the mismatch finder.

One row per instant; the header names the channels. Column classes follow from the name:

- ``time_s``: time since the start of the recording, seconds, strictly increasing (first column);
- temperature sensors end in ``_c`` (degrees Celsius), e.g. ``ambient_c``, ``t5_c``;
- error / displacement channels start with ``E_`` (ISO 230 names of the 5-axis machine:
  ``E_X0C E_Y0C E_Z0T E_R0T`` in um, ``E_A0C E_B0C E_C0C`` in um/m) or end in ``_um``
  (``ch1_um``, lathe tool positions ``T01_X_um``);
- every other column is an input of the machine (``spindle_rpm``, ``coolant_on`` ...).

This is the format of ``thermal-comp sim --csv`` and of ``shared/data/fl_thermal``.
Bad input raises :class:`RecordingError` naming the line, column and value. A truncated
last line is reported and the rows before it are kept (``strict=False``, the default).
"""
from __future__ import annotations

import csv
import io
import math
import pathlib
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

TIME_COLUMN = "time_s"
ANGULAR_ERRORS = ("E_A0C", "E_B0C", "E_C0C")


class RecordingError(ValueError):
    """A recording file is malformed; the message names line, column and value."""


def column_kind(name: str) -> str:
    """'time', 'sensor', 'error' or 'input' for a column name."""
    if name == TIME_COLUMN:
        return "time"
    if name.startswith("E_") or name.endswith("_um"):
        return "error"
    if name.endswith("_c"):
        return "sensor"
    return "input"


def error_unit(name: str) -> str:
    """'um/m' for the angular location errors, else 'um'."""
    return "um/m" if name in ANGULAR_ERRORS else "um"


@dataclass
class Recording:
    """A recording in memory: time vector and one float array per column."""

    time_s: np.ndarray
    columns: dict[str, np.ndarray]
    source: str = ""
    warnings: list[str] = field(default_factory=list)

    def names(self, kind: str) -> list[str]:
        return [c for c in self.columns if column_kind(c) == kind]

    @property
    def sensors(self) -> dict[str, np.ndarray]:
        return {c: self.columns[c] for c in self.names("sensor")}

    @property
    def errors(self) -> dict[str, np.ndarray]:
        return {c: self.columns[c] for c in self.names("error")}

    @property
    def inputs(self) -> dict[str, np.ndarray]:
        return {c: self.columns[c] for c in self.names("input")}

    def __len__(self) -> int:
        return len(self.time_s)

    def slice(self, start: int, stop: int) -> "Recording":
        return Recording(self.time_s[start:stop].copy(),
                         {k: v[start:stop].copy() for k, v in self.columns.items()},
                         source=self.source, warnings=list(self.warnings))


def read_recording_csv(path: str | pathlib.Path, strict: bool = False,
                       sample_period_s: float | None = None) -> Recording:
    """Read a recording CSV. Empty cells and ``nan`` become NaN (a failed reading).

    With ``strict=False`` a truncated final line (fewer cells than the header) is dropped
    with a warning in ``Recording.warnings``; any other malformed line raises.
    ``sample_period_s``: the file has no ``time_s`` column; row i is at i x the period.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        line = path.read_bytes()[:exc.start].count(b"\n") + 1
        raise RecordingError(f"{path}: line {line}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x}); "
                             "not a recording CSV") from None
    return read_recording_text(text, str(path), strict, sample_period_s)


def _header_and_lines(text: str, source: str) -> tuple[list[str], list[list[str]]]:
    if "\x00" in text:
        raise RecordingError(f"{source}: line {text[:text.index(chr(0))].count(chr(10)) + 1}: a NUL byte; "
                             "a binary file, not a recording CSV")
    with io.StringIO(text, newline="") as f:
        reader = csv.reader(f)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise RecordingError(f"{source}: empty file, expected a header starting with '{TIME_COLUMN}'")
        except csv.Error as exc:
            raise RecordingError(f"{source}: line 1: {exc}") from None
        try:
            return header, list(reader)
        except csv.Error as exc:
            raise RecordingError(f"{source}: line {reader.line_num}: {exc}") from None


def _check_period(sample_period_s: float | None, source: str) -> None:
    if sample_period_s is not None and not (isinstance(sample_period_s, (int, float))
                                            and math.isfinite(sample_period_s) and sample_period_s > 0):
        raise RecordingError(f"{source}: sample period {sample_period_s!r} must be a finite number of seconds > 0")


def read_recording_text(text: str, source: str, strict: bool = False,
                        sample_period_s: float | None = None) -> Recording:
    """:func:`read_recording_csv` on text already in memory; errors and warnings name ``source``
    (the user's file, never a temporary copy). Without a ``time_s`` first column the time is
    row index x ``sample_period_s`` (refused when no period is given)."""
    _check_period(sample_period_s, source)
    header, lines = _header_and_lines(text, source)
    timed = bool(header) and header[0] == TIME_COLUMN
    if not timed and sample_period_s is None:
        raise RecordingError(f"{source}: line 1: first column must be '{TIME_COLUMN}', got {header[:1]} "
                             "(no time column: give the sample period, e.g. --sample-period-s 60)")
    if timed and sample_period_s is not None:
        raise RecordingError(f"{source}: line 1: has a '{TIME_COLUMN}' column and a sample period was given; "
                             "use one of them")
    dupes = {h for h in header if header.count(h) > 1}
    if dupes:
        raise RecordingError(f"{source}: line 1: duplicate column(s) {sorted(dupes)}")
    if any(not h for h in header):
        raise RecordingError(f"{source}: line 1: empty column name at position {header.index('') + 1}")
    rows, warnings = _rows(header, lines, source, strict)
    data = np.asarray(rows, dtype=float)
    if not timed:
        t = np.arange(data.shape[0], dtype=float) * float(sample_period_s)
        warnings.append(f"{source}: no '{TIME_COLUMN}' column: time = row index x {sample_period_s:g} s")
        return Recording(t, {name: data[:, j].copy() for j, name in enumerate(header)}, source=source,
                         warnings=warnings)
    t = data[:, 0]
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise RecordingError(f"{source}: line {bad + 2}: column '{TIME_COLUMN}': {t[bad]!r} is not a time")
    steps = np.diff(t)
    if np.any(steps <= 0):
        bad = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise RecordingError(f"{source}: line {bad + 2}: column '{TIME_COLUMN}': {t[bad]!r} does not "
                             f"increase (previous {t[bad - 1]!r})")
    cols = {name: data[:, j].copy() for j, name in enumerate(header) if j > 0}
    return Recording(t.copy(), cols, source=source, warnings=warnings)


def _rows(header: list[str], lines: list[list[str]], source: str, strict: bool) -> tuple[list, list[str]]:
    rows: list[list[float]] = []
    warnings: list[str] = []
    for i, cells in enumerate(lines):
        lineno = i + 2
        if not cells:
            continue
        if len(cells) != len(header):
            if i == len(lines) - 1 and len(cells) < len(header) and not strict:
                warnings.append(f"{source}: line {lineno}: truncated ({len(cells)} of {len(header)} cells), "
                                f"dropped; data up to line {lineno - 1} kept")
                break
            raise RecordingError(f"{source}: line {lineno}: {len(cells)} cells, header has {len(header)}")
        row = []
        for name, cell in zip(header, cells):
            cell = cell.strip()
            if cell == "" or cell.lower() == "nan":
                value = math.nan
            else:
                try:
                    value = float(cell)
                except ValueError:
                    raise RecordingError(f"{source}: line {lineno}: column '{name}': "
                                         f"{cell!r} is not a number") from None
            row.append(value)
        rows.append(row)
    if not rows:
        raise RecordingError(f"{source}: no data rows")
    return rows, warnings


def write_recording_csv(path: str | pathlib.Path, time_s: Iterable[float],
                        columns: Mapping[str, Iterable[float]], precision: int = 6) -> None:
    """Write a recording CSV (``time_s`` first, then ``columns`` in the given order)."""
    path = pathlib.Path(path)
    t = np.asarray(list(time_s) if not isinstance(time_s, np.ndarray) else time_s, dtype=float)
    names = list(columns)
    if TIME_COLUMN in names:
        raise RecordingError(f"column '{TIME_COLUMN}' is written from time_s; remove it from columns")
    arrays = []
    for n in names:
        a = np.asarray(columns[n], dtype=float)
        if a.shape != t.shape:
            raise RecordingError(f"column '{n}': {a.shape[0] if a.ndim else 0} values, "
                                 f"time_s has {t.shape[0]}")
        arrays.append(a)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    fmt = f"{{:.{precision}g}}"
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow([TIME_COLUMN] + names)
        for i in range(t.shape[0]):
            w.writerow([f"{t[i]:.10g}"] +
                       ["nan" if not math.isfinite(a[i]) else fmt.format(a[i]) for a in arrays])
    tmp.replace(path)
