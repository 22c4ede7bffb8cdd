"""Append-only audit log of every offset write to a CNC (pure core).

One CSV line per axis per write, flushed and fsync'ed before the call returns, so that a
crash loses nothing already written and the file always says what the machine was told:

    time_s,wall_time_utc,axis,commanded_um,applied_um,confirmed,limits,note

``time_s`` is the ROS/simulated time of the write, ``wall_time_utc`` the host clock,
``commanded_um`` the model's command, ``applied_um`` what the CNC read back (empty if the
write was not confirmed), ``limits`` the LIMIT_* flags as names (``absolute|rate``).
Events that are not writes (start-up adoption of held offsets, lifecycle transitions,
runtime limit changes) are lines with ``confirmed`` 0, empty numbers and the text in
``note`` (a write's ``note`` is empty), so the file tells the whole story in order.
The file is opened in append mode and never truncated; a header is written only to an
empty file.
"""
from __future__ import annotations

import csv
import datetime as _dt
import io
import math
import os
import pathlib
from typing import Iterable

from cnc_bridge.safety_envelope import flag_names

HEADER = ("time_s", "wall_time_utc", "axis", "commanded_um", "applied_um", "confirmed", "limits",
          "note")


def _num(v: float | None) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.6f}"


class AuditLog:
    """Append-only CSV writer; ``log_write`` per write, ``close`` at shutdown."""

    def __init__(self, path: str | os.PathLike):
        self.path = pathlib.Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "a", newline="", encoding="utf-8")
        if self._f.tell() == 0:
            self._write_rows([HEADER])

    def _write_rows(self, rows: Iterable[Iterable[str]]) -> None:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerows(rows)
        self._f.write(buf.getvalue())
        self._f.flush()
        os.fsync(self._f.fileno())

    def log_write(self, time_s: float, entries: Iterable[tuple[str, float, float | None, int]]) -> None:
        """Log one write: ``entries`` = (axis, commanded_um, applied_um or None, flags)."""
        wall = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")
        rows = [(f"{time_s:.6f}", wall, axis, _num(cmd), _num(app),
                 "1" if app is not None and math.isfinite(app) else "0", flag_names(flags), "")
                for axis, cmd, app, flags in entries]
        self._write_rows(rows)

    def log_event(self, time_s: float, axis: str, note: str, flags: int = 0) -> None:
        """Log an event that wrote nothing (``axis`` may be empty: the whole bridge)."""
        wall = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")
        self._write_rows([(f"{time_s:.6f}", wall, axis, "", "", "0", flag_names(flags), note)])

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


def read_audit_log(path: str | os.PathLike) -> list[dict[str, str]]:
    """All rows of an audit log as dicts (for tools and tests)."""
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))
