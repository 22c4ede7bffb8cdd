"""Calibrate a twin to one unit from what its cell records: the temperatures (every row, noise
from their second differences), the machine inputs, and the probes of the error channels
(sparse rows, weighted by the probes' stated uncertainty). Training = everything up to
``train_until_s``; the later probes are held out and only scored. No rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_twin.calibrate.fit import CalibrationResult, calibrate
from thermal_twin.machine.schema import Machine, load_machine

from thermal_eval.learn.probes import MIN_PROBES, ProbeDataError, ProbeSet

#: at most this many training rows are fitted (the probe rows always among them)
MAX_TRAIN_ROWS = 3000


class LearnError(ValueError):
    """The unit cannot be learned from this recording; the message names the cause."""


@dataclass
class UnitFit:
    """The calibrated twin of the unit and what it was fitted on."""

    machine: Machine                  # the twin it started from
    calibration: CalibrationResult
    components: list[str]             # error channels learned from probes
    train_until_s: float
    probes_train: int
    probes_held_out: int
    fit_rec: Recording | None = None  # the rows fitted and scored, probes in the error columns
    holdout: float = 0.0              # the fraction of ``fit_rec`` after the fit window

    @property
    def spec(self) -> dict:
        return self.calibration.spec


def fit_rows(rec: Recording, probe_times: np.ndarray, train_until_s: float) -> np.ndarray:
    """Rows kept for the fit: every k-th training row (at most MAX_TRAIN_ROWS), every probe row,
    every k-th held-out row (held-out rows are only scored)."""
    t = rec.time_s
    n_train = int(np.searchsorted(t, train_until_s, side="right"))
    k = max(1, math.ceil(n_train / MAX_TRAIN_ROWS))
    keep = np.zeros(t.size, bool)
    keep[::k] = True
    keep[np.searchsorted(t, probe_times)] = True
    keep[0] = keep[-1] = True
    return np.flatnonzero(keep)


def probe_recording(rec: Recording, probes: ProbeSet, components: list[str]) -> Recording:
    """``rec`` with the error columns of ``components``: the probes at their rows, NaN elsewhere
    (every probe instant must be an instant of the recording: a cell probes at its instants)."""
    idx = np.searchsorted(rec.time_s, probes.time_s)
    ok = (idx < len(rec)) & (np.abs(rec.time_s[np.minimum(idx, len(rec) - 1)] - probes.time_s) < 1e-3)
    if not ok.all():
        t = probes.time_s[~ok][0]
        raise ProbeDataError(f"probes {probes.source}: t = {t:.3f} s is no instant of the recording")
    cols = dict(rec.columns)
    for c in components:
        col = np.full(len(rec), np.nan)
        col[idx] = probes.values[c]
        cols[c] = col
    return Recording(rec.time_s, cols, source=rec.source, warnings=list(rec.warnings))


def learn_unit_twin(twin, rec: Recording, probes: ProbeSet, train_until_s: float, max_nfev: int = 20,
                    progress: Callable[[str], None] | None = None) -> UnitFit:
    """Fit ``twin``'s parameters within its tolerances to the unit (module docstring)."""
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    components = [c for c in machine.errors if c in probes.values]
    if not components:
        raise LearnError(f"probes {probes.source}: none of the twin's error channels {list(machine.errors)} "
                         f"was probed (probed: {sorted(probes.values)})")
    train = probes.window(t1=train_until_s + 1e-6)
    few = [c for c in components if train.count(c) < MIN_PROBES]
    if few:
        raise LearnError(f"--train-h: only {min(train.count(c) for c in few)} probes of {few[0]!r} up to "
                         f"t = {train_until_s / 3600.0:.1f} h, need at least {MIN_PROBES}")
    full = probe_recording(rec, probes, components)
    rows = fit_rows(full, probes.time_s, train_until_s)
    fit_rec = Recording(full.time_s[rows], {k: v[rows] for k, v in full.columns.items()}, source=rec.source)
    n_train = int(np.searchsorted(fit_rec.time_s, train_until_s, side="right"))
    holdout = 1.0 - n_train / len(fit_rec)
    if not 0.05 <= holdout <= 0.8:
        raise LearnError(f"--train-h {train_until_s / 3600.0:.1f}: leaves {100 * holdout:.0f} % of the "
                         f"{(rec.time_s[-1] - rec.time_s[0]) / 3600.0:.1f} h recording held out; "
                         "keep 5-80 % for the held-out check")
    cal = calibrate(machine, fit_rec, holdout_fraction=holdout, max_nfev=max_nfev, progress=progress,
                    sigma={c: probes.noise[c] for c in components})
    return UnitFit(machine, cal, components, float(train_until_s), int(train.time_s.size),
                   int(probes.window(t0=train_until_s + 1e-6).time_s.size), fit_rec, holdout)
