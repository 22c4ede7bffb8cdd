"""The runs of a several-recording ``learn``: every source (files, a folder, a glob, a manifest:
thermal_comp_common.recording_sources, the reader evaluate, calibrate and replay share) read as
a cell recording (learn.probes: temperatures, inputs, probes of the total error), checked before
the long work. Each refusal is one line naming the run and the field. No rclpy.

Rules: a unit twin is per unit, so every run must carry the same manifest ``unit`` (all blank is
one unit: files, folders and globs carry none); every run has the first run's columns and probed
components; every run has at least ``MIN_CHANNEL_VALUES`` probes of every probed component (what a
calibration channel needs); a file listed twice or two runs of one name are refused by the reader.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from thermal_comp_common.bags.recording import MIN_CHANNEL_VALUES
from thermal_comp_common.recording_csv import Recording
from thermal_comp_common.recording_sources import DatasetError, RunEntry, resolve_runs

from thermal_eval.learn.probes import ProbeDataError, ProbeSet, cell_recording


@dataclass
class CellRun:
    """One run as learn sees it: its manifest entry, what the cell recorded (no error column)
    and its probes (instants on the run's own clock, values since the run's start)."""

    entry: RunEntry
    rec: Recording
    probes: ProbeSet

    @property
    def name(self) -> str:
        return self.entry.name

    @property
    def hours(self) -> float:
        return float(self.rec.time_s[-1] - self.rec.time_s[0]) / 3600.0


def _one_unit(entries: Sequence[RunEntry]) -> None:
    units = {e.unit for e in entries}
    if len(units) > 1:
        first = entries[0]
        other = next(e for e in entries if e.unit != first.unit)
        raise DatasetError(f"run {other.name!r}: field 'unit' = {other.unit!r} differs from run {first.name!r} "
                           f"({first.unit!r}); a unit twin is learned from one unit's runs")


def _check_same(first: CellRun, run: CellRun) -> None:
    for what, a, b in (("columns", sorted(first.rec.columns), sorted(run.rec.columns)),
                       ("probed components", sorted(first.probes.values), sorted(run.probes.values))):
        if a != b:
            diff = sorted(set(a) ^ set(b))
            raise DatasetError(f"run {run.name!r} ({run.entry.path}): field '{what}' differs from run "
                               f"{first.name!r}: {', '.join(diff[:6])} in one of them only")


def enough_probes(run: CellRun, probes: ProbeSet, where: str) -> None:
    """At least MIN_CHANNEL_VALUES probes of every component in ``probes`` (a part of ``run``)."""
    for c in probes.values:
        n = probes.count(c)
        if n < MIN_CHANNEL_VALUES:
            raise DatasetError(f"run {run.name!r} ({run.entry.path}): field {c!r} has {n} probes {where}, "
                               f"need at least {MIN_CHANNEL_VALUES}")


def cell_runs(sources: Sequence[str], noise: dict[str, float] | None = None,
              sample_period_s: float | None = None) -> list[CellRun]:
    """Every run the sources name, read and checked (module docstring); ``sample_period_s``: every
    CSV without a time column."""
    entries = resolve_runs(sources)
    _one_unit(entries)
    runs: list[CellRun] = []
    for e in entries:
        try:
            rec, probes = cell_recording(e.path, noise, sample_period_s)
        except (ProbeDataError, ValueError, OSError) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise DatasetError(f"run {e.name!r}: {msg}") from None
        if rec.time_s.size < 2 or not np.all(np.diff(rec.time_s) > 0):
            raise DatasetError(f"run {e.name!r} ({e.path}): field 'time_s' must increase")
        run = CellRun(e, rec, probes)
        if runs:
            _check_same(runs[0], run)
        runs.append(run)
    return runs
