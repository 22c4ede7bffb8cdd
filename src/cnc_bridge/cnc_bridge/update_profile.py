"""Where the bridge's time goes for each prediction it answers (pure: no rclpy).

The cnc_bridge node, when given ``profile_path``, times every prediction from the moment its
callback starts: the transform (eq. 6.3-6.5), the envelope step, the CNC write with its
read-back (the backend call as the node sees it, and the round trip(s) as the OPC UA
client's event loop sees them; the difference is the call's own work around them), the ``offsets`` publication, the audit log line (flushed and fsync'ed) and the
SimSync acknowledgement. One CSV row per prediction, written when the node exits; the wall
clock of the callback start lets ``bench graph`` join it to the DDS publication times of the
same instant (thermal_comp.demo.graph_profile) and so measure the DDS hop into the bridge too.
"""
from __future__ import annotations

import csv
import os
import pathlib
import time

#: the timed phases, in the order they happen within one prediction
PHASES = ("transform", "envelope", "cnc_call", "publish", "audit", "ack")
COLUMNS = ("stamp_ns", "received_wall_s", *(f"{p}_ms" for p in PHASES), "round_trip_ms", "round_trips")


class UpdateProfile:
    """Collects one row per prediction: :meth:`begin`, :meth:`lap` after each phase, :meth:`end`."""

    def __init__(self) -> None:
        self.rows: list[dict[str, float]] = []
        self._row: dict[str, float] | None = None
        self._t = 0.0

    def begin(self, stamp_ns: int) -> None:
        self._row = {"stamp_ns": stamp_ns, "received_wall_s": time.time()}
        self._t = time.perf_counter()

    def lap(self, phase: str) -> None:
        """The time since the previous lap (or :meth:`begin`) was spent in ``phase``."""
        if self._row is None:
            return
        now = time.perf_counter()
        self._row[f"{phase}_ms"] = self._row.get(f"{phase}_ms", 0.0) + (now - self._t) * 1e3
        self._t = now

    def note(self, **values: float) -> None:
        if self._row is not None:
            self._row.update(values)

    def end(self) -> None:
        if self._row is not None:
            self.rows.append(self._row)
            self._row = None

    def write_csv(self, path: str | os.PathLike) -> None:
        p = pathlib.Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, COLUMNS, restval="", extrasaction="ignore")
            w.writeheader()
            w.writerows(self.rows)


def read_profile(path: str | os.PathLike) -> list[dict[str, float]]:
    """The rows of a profile CSV, numbers as floats (an empty cell: the phase did not run)."""
    with open(path, newline="", encoding="utf-8") as f:
        return [{k: float(v) for k, v in row.items() if v != ""} for row in csv.DictReader(f)]
