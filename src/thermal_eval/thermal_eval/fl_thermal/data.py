"""The FL_THERMAL recording as the benchmark uses it: import, checks, the authors' split.

``$THERMAL_COMP_SHARED/data/fl_thermal/fl_thermal.csv`` or the bench's ``--csv`` (MIT, CAIVIAC/FL_THERMAL; README and LICENSE beside
it): 11,115 rows at 15 s, spindle speed, 5 displacement channels (um), 16 temperatures.
Displacements are taken relative to the first row. The authors split the rows
chronologically: first 60 % train (rows 0-6668), next 20 % test (6669-8891), last 20 %
validation (8892-11114). No rclpy here.
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from thermal_comp_common.metrics import mae  # noqa: F401 (the benchmark's metric, used through this module)
from thermal_comp_common.recording_csv import read_recording_csv

from thermal_eval.evaluate.spec import EvaluationData, Split

CHANNELS = ("ch1", "ch2", "ch3", "ch4", "ch5")
SENSORS = tuple(f"t{i}" for i in range(1, 17))
SPINDLE_COLUMN = "spindle_rpm"
TRAIN_FRACTION = 0.6
TEST_FRACTION = 0.2

class FlThermalError(ValueError):
    """Bad benchmark input; the message names the file, column or option and its value."""


SHARED_ENV = "THERMAL_COMP_SHARED"
CSV_RELATIVE = pathlib.Path("data") / "fl_thermal" / "fl_thermal.csv"


def default_csv_path() -> pathlib.Path:
    """``$THERMAL_COMP_SHARED/data/fl_thermal/fl_thermal.csv`` (the pytest plugin sets the variable
    for tests); one clear error naming both ways to give it when the variable is unset or wrong."""
    env = os.environ.get(SHARED_ENV)
    if not env:
        raise FlThermalError(f"FL_THERMAL data: environment variable {SHARED_ENV} is not set; set it to the "
                             f"shared/ folder (holding {CSV_RELATIVE}) or give the CSV with --csv PATH")
    path = pathlib.Path(env) / CSV_RELATIVE
    if not path.is_file():
        raise FlThermalError(f"FL_THERMAL data: {SHARED_ENV}={env!r} has no {CSV_RELATIVE}; set it to the "
                             f"shared/ folder or give the CSV with --csv PATH")
    return path


@dataclass
class FlThermalData:
    """The recording as the benchmark uses it (displacements relative to the first row)."""

    recording: Any                      # thermal_comp_common.recording_csv.Recording (for the replay)
    time_s: np.ndarray
    temperatures: np.ndarray            # N x 16, degC, columns SENSORS
    spindle_rpm: np.ndarray
    displacement_um: dict[str, np.ndarray]

    def __len__(self) -> int:
        return int(self.time_s.size)


def load_fl_thermal(path: str | pathlib.Path | None = None, rows: int | None = None,
                    every: int = 1) -> FlThermalData:
    """Read the FL_THERMAL CSV; optionally its first ``rows`` rows, every ``every``-th row."""
    path = pathlib.Path(path) if path is not None else default_csv_path()
    if not path.is_file():
        raise FlThermalError(f"--csv: {str(path)!r} is not a file (or set {SHARED_ENV} to the shared/ folder "
                             f"and leave --csv out)")
    if not isinstance(every, int) or every < 1:
        raise FlThermalError(f"every: {every!r} must be an integer >= 1")
    if rows is not None and (not isinstance(rows, int) or rows < 50):
        raise FlThermalError(f"rows: {rows!r} must be an integer >= 50")
    rec = read_recording_csv(path)
    needed = [SPINDLE_COLUMN] + [f"{c}_um" for c in CHANNELS] + [f"{s}_c" for s in SENSORS]
    missing = [c for c in needed if c not in rec.columns]
    if missing:
        raise FlThermalError(f"{path}: column(s) {missing} missing (have {sorted(rec.columns)})")
    for c in needed:
        bad = np.flatnonzero(~np.isfinite(rec.columns[c]))
        if bad.size:
            raise FlThermalError(f"{path}: column '{c}': row {int(bad[0])} is {rec.columns[c][bad[0]]!r} "
                                 f"({bad.size} non-finite values); the benchmark needs complete rows")
    stop = len(rec) if rows is None else min(rows, len(rec))
    idx = np.arange(0, stop, every)
    sub = type(rec)(rec.time_s[idx].copy(), {k: v[idx].copy() for k, v in rec.columns.items() if k in needed},
                    source=rec.source, warnings=list(rec.warnings))
    if len(sub) < 50:
        raise FlThermalError(f"rows/every: only {len(sub)} rows left, need >= 50")
    disp = {c: sub.columns[f"{c}_um"] - sub.columns[f"{c}_um"][0] for c in CHANNELS}
    temps = np.column_stack([sub.columns[f"{s}_c"] for s in SENSORS])
    return FlThermalData(sub, sub.time_s, temps, sub.columns[SPINDLE_COLUMN].copy(), disp)


@dataclass(frozen=True)
class Splits:
    """Chronological row ranges: train [0, n_train), test [n_train, test_end), validation [test_end, n)."""

    n_train: int
    test_end: int
    n: int

    @classmethod
    def authors(cls, n: int) -> "Splits":
        """60 / 20 / 20 % as the authors cut it (11115 rows: 6669 / 8892)."""
        n_train = int(TRAIN_FRACTION * n)
        test_end = int((TRAIN_FRACTION + TEST_FRACTION) * n)
        if not 0 < n_train < test_end < n:
            raise FlThermalError(f"rows: {n} rows cannot be split 60/20/20")
        return cls(n_train, test_end, n)

    @property
    def test(self) -> slice:
        return slice(self.n_train, self.test_end)

    @property
    def validation(self) -> slice:
        return slice(self.test_end, self.n)


def as_evaluation_data(data: FlThermalData, splits: Splits | None = None):
    """The same rows as the generic ``evaluate`` data (names ``t1..t16`` / ``ch1..ch5``, the spindle
    speed as the one machine input, ``splits`` or the authors' split), so the benchmark runs the
    generic models (:mod:`thermal_eval.evaluate.open_loop_models`) and baselines on FL_THERMAL."""
    s = splits or Splits.authors(len(data))
    return EvaluationData(data.time_s, data.temperatures, list(SENSORS), data.spindle_rpm[:, None],
                          [SPINDLE_COLUMN], dict(data.displacement_um), Split(s.n_train, s.validation, s.test, s.n),
                          "FL_THERMAL")
