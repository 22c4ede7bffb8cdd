"""The unit twin fitted on several runs of one unit: the bounded calibration of
``thermal-comp calibrate`` on the training runs' probes and temperatures jointly, every run
simulated alone from its own start (thermal_twin.calibrate.runs), the probes weighted by their
stated uncertainty as for one recording. No rclpy.

What decides the adoption (the validation probes, never fitted):
- the split gives validation runs: every probe of those runs, each run simulated from its own
  start; the training runs are fitted whole;
- it gives none: the last ``validate_h`` hours of every training run (default the last quarter of
  each), as the single-recording learn keeps the end of its training window apart.

A run's errors count from its start, as learn reads one recording (the twin starts in the steady
state of the run's first readings, its errors 0 there): in the joint fit every run's probe
columns hold 0 at its first row (``calibrate_runs`` references each run to its first finite
value; a probe at the first row is that reference). One training run without validation runs is
fitted as one recording (learn.unit_fit, its last hours held out of the fit).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_comp_common.run_splits import RunFold
from thermal_twin.calibrate.fit import CalibrationResult
from thermal_twin.calibrate.runs import calibrate_runs
from thermal_twin.machine.schema import Machine

from thermal_eval.learn.runs.sources import CellRun, enough_probes
from thermal_eval.learn.unit_fit import LearnError, fit_rows, learn_unit_twin, probe_recording

#: without validation runs, this share of every training run (its end) decides the adoption
VALIDATE_SHARE = 0.25


@dataclass
class RunsFit:
    """The calibrated unit twin and what decided and scored it: per run index its fit end (run
    clock, s; inf: fitted whole; absent: not fitted) and its validation probes (mask)."""

    machine: Machine
    calibration: CalibrationResult
    components: list[str]
    fit_until: dict[int, float]
    validation: dict[int, np.ndarray]
    rule: str
    wall_s: float

    @property
    def spec(self) -> dict:
        return self.calibration.spec


def windows(runs: Sequence[CellRun], fold: RunFold, validate_h: float | None) -> tuple[dict, dict, str]:
    """(fit end per training run, validation mask per run, the rule in words): module docstring."""
    if fold.validation:
        if validate_h is not None:
            raise LearnError(f"--validate-h {validate_h:g}: the split gives validation runs "
                             f"({', '.join(runs[i].name for i in fold.validation)}); they decide alone")
        fit_until = {i: math.inf for i in fold.train}
        val = {i: np.ones(runs[i].probes.time_s.size, bool) for i in fold.validation}
        return fit_until, val, "every probe of the validation runs (each run from its own start)"
    fit_until, val = {}, {}
    for i in fold.train:
        t = runs[i].rec.time_s
        span = float(t[-1] - t[0])
        keep = VALIDATE_SHARE * span if validate_h is None else 3600.0 * float(validate_h)
        if not 0.0 < keep < span:
            raise LearnError(f"--validate-h {validate_h:g}: not within the {span / 3600.0:.1f} h of run "
                             f"{runs[i].name!r}")
        fit_until[i] = float(t[-1]) - keep
        val[i] = runs[i].probes.time_s > fit_until[i]
    what = "the last quarter" if validate_h is None else f"the last {validate_h:g} h"
    return fit_until, val, f"{what} of every training run (the split gives no validation run)"


def _fit_recording(run: CellRun, components: list[str], until: float) -> Recording:
    """The run's rows up to ``until`` (at most learn's row budget, every probe row), its probes in
    the error columns, 0 at the first row: the start its errors count from."""
    full = probe_recording(run.rec, run.probes, components)
    for c in components:
        full.columns[c][0] = 0.0
    rows = fit_rows(full, run.probes.time_s, until)
    rows = rows[full.time_s[rows] <= until]
    return Recording(full.time_s[rows], {k: v[rows] for k, v in full.columns.items()}, source=run.rec.source)


def fit_runs(machine: Machine, runs: Sequence[CellRun], fold: RunFold, validate_h: float | None,
             max_nfev: int, progress: Callable[[str], None] | None = None) -> RunsFit:
    """The unit twin calibrated on ``fold``'s training runs (module docstring)."""
    t0 = time.perf_counter()
    components = [c for c in machine.errors if c in runs[0].probes.values]
    if not components:
        raise LearnError(f"run {runs[0].name!r}: none of the twin's error channels {list(machine.errors)} was "
                         f"probed (probed: {sorted(runs[0].probes.values)})")
    fit_until, val, rule = windows(runs, fold, validate_h)
    noise = {c: runs[0].probes.noise[c] for c in components}
    for i, until in fit_until.items():
        enough_probes(runs[i], runs[i].probes.window(t1=until + 1e-6), "in its fit window")
    for i in fold.validation:
        enough_probes(runs[i], runs[i].probes, "(a validation run)")
    train = list(fold.train)
    if len(train) == 1 and not fold.validation:
        i = train[0]
        cal = learn_unit_twin(machine, runs[i].rec, runs[i].probes, fit_until[i], max_nfev=max_nfev,
                              progress=progress).calibration
    else:
        order = train + ([] if len(train) > 1 else list(fold.validation))
        recs = [_fit_recording(runs[i], components, fit_until.get(i, math.inf)) for i in order]
        names = [runs[i].name for i in order]
        inner = RunFold(fold.name, tuple(range(len(train))), (), tuple(range(len(train), len(order))))
        cal = calibrate_runs(machine, recs, names, fold=inner, max_nfev=max_nfev, progress=progress,
                             sigma=noise).result
    return RunsFit(machine, cal, components, fit_until, val, rule, time.perf_counter() - t0)
