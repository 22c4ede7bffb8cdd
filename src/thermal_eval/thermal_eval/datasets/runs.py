"""Runs of a data set as the models see them, and one fold's training runs + one held-out run
as one :class:`~thermal_eval.evaluate.spec.EvaluationData`.

Every run is read by the one reader of real files with the same spec (columns, units,
mapping) and must give the same temperatures, channels and inputs. Each run keeps its own
start reference (displacements relative to their first finite value; optionally the
temperatures too: :func:`from_start`) and its own time axis.
For a fold the training runs are laid end to end (each after the previous one's last row
plus one sample period), then the held-out run; its first row closes the calibration phase
(its displacement is its start reference, 0, by definition), so the probing clock of the
adaptive mode starts at the start of that run. Dynamic models carry their state from one run
into the next unless each run is preceded by its rest (:func:`at_rest`;
:mod:`thermal_eval.datasets.run_start` decides). ``run_id`` marks each row's run (-1: a rest row),
so that changes are measured inside one run only. Pure.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from thermal_comp_common.recording_sources import DatasetError, RunEntry
from thermal_eval.evaluate.spec import EvaluationData, SpecError, Split, load_evaluation_data

#: fewest rows of a run (a run shorter than this cannot be scored)
MIN_RUN_ROWS = 10


@dataclass
class Run:
    entry: RunEntry
    data: EvaluationData                     # the whole run (every row a training row)
    notes: list[str] = field(default_factory=list)

    @property
    def hours(self) -> float:
        t = self.data.time_s
        return float(t[-1] - t[0]) / 3600.0


def _check_same(first: Run, run: Run) -> None:
    a, b = first.data, run.data
    for what, x, y in (("temperatures", a.sensors, b.sensors), ("displacements", a.channels, b.channels),
                       ("inputs", a.input_names, b.input_names)):
        if list(x) != list(y):
            extra = sorted(set(y) - set(x)) or sorted(set(x) - set(y))
            raise DatasetError(f"{run.entry.path}: field '{what}' = {list(y)[:8]}: differs from the first run "
                               f"{first.entry.name!r} ({list(x)[:8]}; first difference {extra[:1] or 'order'})")


def load_runs(entries: Sequence[RunEntry], spec: Mapping[str, Any] | None = None, map_file: str | None = None,
              map_flags: Sequence[str] | None = None) -> list[Run]:
    """Read every run with the same spec; a run the spec does not fit is one error naming its file."""
    runs: list[Run] = []
    spec = {k: v for k, v in dict(spec or {}).items() if k != "split"}
    for e in entries:
        try:
            d = load_evaluation_data(e.path, spec, map_file, map_flags, whole=True)
        except (SpecError, ValueError) as exc:
            msg = str(exc)
            raise DatasetError(msg if e.path in msg else f"{e.path}: {msg}") from None
        if len(d) < MIN_RUN_ROWS:
            raise DatasetError(f"{e.path}: field 'rows' = {len(d)}: a run needs at least {MIN_RUN_ROWS} rows")
        d.time_s = d.time_s - d.time_s[0]
        run = Run(e, d, list(d.notes))
        if runs:
            _check_same(runs[0], run)
        runs.append(run)
    return runs


def _relative(y: np.ndarray) -> np.ndarray:
    ok = np.flatnonzero(np.isfinite(y))
    return y - y[ok[0]] if ok.size else y


def segments(run: Run, k: int) -> list[Run]:
    """One run cut into ``k`` contiguous runs of (nearly) equal rows, each with its own start
    reference and time axis (to score a single long recording across runs)."""
    n = len(run.data)
    if not (isinstance(k, int) and 2 <= k <= n // MIN_RUN_ROWS):
        raise DatasetError(f"segments: {k!r} must be an integer in 2..{n // MIN_RUN_ROWS} for {n} rows")
    bounds = np.linspace(0, n, k + 1).round().astype(int)
    out = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        d = run.data
        part = EvaluationData(d.time_s[a:b] - d.time_s[a], d.temperatures[a:b], d.sensors,
                              None if d.inputs is None else d.inputs[a:b], d.input_names,
                              {c: _relative(v[a:b]) for c, v in d.displacement_um.items()},
                              Split(b - a, slice(b - a, b - a), slice(b - a, b - a), b - a),
                              f"{d.source} rows {a}-{b - 1}", [])
        e = run.entry
        out.append(Run(RunEntry(e.path, f"{e.name}#{i + 1}", e.unit, e.programme, e.date, e.hall_setpoint_c),
                       part))
    return out


def _step(t: np.ndarray) -> float:
    d = np.diff(t)
    return float(np.median(d)) if d.size else 1.0


def _end_to_end(parts: Sequence[EvaluationData], n_train: int, test: slice, source: str,
                notes: list[str]) -> EvaluationData:
    """Runs laid end to end: each after the previous one's last row plus one sample period."""
    times, off = [], 0.0
    for p in parts:
        times.append(p.time_s + off)
        off = times[-1][-1] + _step(p.time_s)
    n = sum(len(p) for p in parts)
    ids = [np.zeros(len(p), int) if p.run_id is None else p.run_id for p in parts]
    return EvaluationData(np.concatenate(times), np.vstack([p.temperatures for p in parts]), parts[0].sensors,
                          None if parts[0].inputs is None else np.vstack([p.inputs for p in parts]),
                          parts[0].input_names,
                          {c: np.concatenate([p.displacement_um[c] for p in parts]) for c in parts[0].channels},
                          Split(n_train, slice(n, n), test, n), source, notes,
                          np.concatenate([np.where(r < 0, -1, k) for k, r in enumerate(ids)]))


def from_start(d: EvaluationData) -> EvaluationData:
    """The run's temperatures relative to its first finite reading of each sensor: the same start
    reference as its displacements, so that a map from temperature changes to displacement
    changes fits every run (absolute temperatures against displacements that start at 0 leave a
    per-run offset, f(T at the start), that no temperature explains). Inputs stay as they are."""
    temps = np.array(d.temperatures, dtype=float, copy=True)
    for j in range(temps.shape[1]):
        ok = np.flatnonzero(np.isfinite(temps[:, j]))
        if ok.size:
            temps[:, j] -= temps[ok[0], j]
    return EvaluationData(d.time_s, temps, d.sensors, d.inputs, d.input_names, d.displacement_um, d.split,
                          d.source, list(d.notes), d.run_id)


def at_rest(d: EvaluationData, hours: float) -> EvaluationData:
    """The run with its first reading held for ``hours`` before it (at its median sample step):
    the assumption that the machine was at rest when the run started, so that dynamic models
    start it in equilibrium instead of carrying the previous run's state. 0: the run as it is."""
    if not (isinstance(hours, (int, float)) and 0 <= hours < 1e4):
        raise DatasetError(f"rest hours {hours!r}: must be a number in [0, 1e4)")
    if hours == 0:
        return d
    step = _step(d.time_s)
    k = max(1, int(round(3600.0 * hours / step)))
    idx = np.r_[np.zeros(k, int), np.arange(len(d))]
    t = np.r_[np.arange(k) * step, k * step + d.time_s - d.time_s[0]]
    return EvaluationData(t, d.temperatures[idx], d.sensors, None if d.inputs is None else d.inputs[idx],
                          d.input_names, {c: v[idx] for c, v in d.displacement_um.items()},
                          Split(t.size, slice(t.size, t.size), slice(t.size, t.size), t.size), d.source, [],
                          np.r_[np.full(k, -1), np.zeros(len(d), int)])


def _prepared(run: Run, rest_h: float, from_start_: bool) -> EvaluationData:
    return at_rest(from_start(run.data) if from_start_ else run.data, rest_h)


def fold_data(runs: Sequence[Run], train: Sequence[int], held_out: int, rest_h: float = 0.0,
              temperatures_from_start: bool = False) -> EvaluationData:
    """The training runs end to end, then the held-out run (its rows after the first are the
    test window; its first row closes the calibration phase). ``rest_h``: every run preceded by
    its first reading held that long (:func:`at_rest`; never scored). ``temperatures_from_start``:
    each run's temperatures relative to its first reading (:func:`from_start`)."""
    parts = [_prepared(runs[i], rest_h, temperatures_from_start) for i in list(train) + [held_out]]
    n_fit = sum(len(p) for p in parts[:-1])
    if n_fit < 50:
        raise DatasetError(f"run split: {n_fit} training rows in {len(train)} runs; the walk-forward needs >= 50")
    held = runs[held_out]
    n = n_fit + len(parts[-1])
    n_train = n - len(held.data) + 1
    return _end_to_end(parts, n_train, slice(n_train, n), held.data.source,
                       [f"trained on {len(train)} runs ({n_fit} rows), scored on run {held.entry.name!r}"
                        + (f", each run after {rest_h:g} h at rest" if rest_h else "")])


def train_data(runs: Sequence[Run], train: Sequence[int], rest_h: float = 0.0,
               temperatures_from_start: bool = False) -> EvaluationData:
    """The training runs end to end, every row a training row (where a fold's models choose)."""
    parts = [_prepared(runs[i], rest_h, temperatures_from_start) for i in train]
    n = sum(len(p) for p in parts)
    return _end_to_end(parts, n, slice(n, n), "training runs", [])
