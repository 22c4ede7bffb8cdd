"""A fleet made with the twin, as a data set: several units of a preset, several runs each.

Unit u of a preset is :func:`thermal_twin.machine.instance.machine_instance` (its parameters
perturbed within the instance tolerances); run k of a unit is one of the preset's scenarios
(programmes, taken in turn) for ``hours`` with its own seed (so its own hall profile and machine
programme draw), simulated by the twin, with probe noise added to every displacement channel
(normal, ``probe_noise_um``: U(k=2) = 0.4 um of the thesis's probing cycle, Table 5.4). The
hall temperature inputs of the twin (its environment) are left out of the recording: a real
cell measures the hall by a sensor, not by a set-point. Written as recording CSVs plus a
manifest (unit, programme, date) in a folder; deterministic for fixed seeds.

The twin knows what a real recording never does: the displacements without the probe noise.
They are written apart (``truth/<run>.csv``, displacement columns only, named by the manifest's
``truth_path``, relative to the recording's folder) where no source of runs looks: a folder of
runs lists its own files only, and the models read the recording alone. :func:`load_truth`
gives them to the scoring (:func:`thermal_eval.datasets.evaluate_runs.evaluate_runs`).
"""
from __future__ import annotations

import csv
import datetime
import pathlib
from dataclasses import dataclass

import numpy as np

from thermal_comp_common.recording_csv import RecordingError, column_kind, read_recording_csv, write_recording_csv
from thermal_comp_common.recording_sources import DatasetError
from thermal_comp_common.run_splits import RunFold
from thermal_eval.datasets.runs import Run
from thermal_twin.machine.instance import machine_instance
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.scenarios import make_timeline, scenario_names
from thermal_twin.sim.simulate import environment_input_names, simulate

PROBE_NOISE_UM = 0.2
FIRST_DAY = datetime.date(2026, 1, 5)
TRUTH_FOLDER = "truth"


@dataclass(frozen=True)
class FleetPlan:
    preset: str
    units: int = 4
    runs_per_unit: int = 5
    hours: float = 5.0
    step_s: float = 60.0
    probe_noise_um: float = PROBE_NOISE_UM
    seed: int = 0


def write_fleet(plan: FleetPlan, folder: str | pathlib.Path) -> pathlib.Path:
    """Simulate every run of the plan into ``folder`` and write ``manifest.csv``; its path."""
    folder = pathlib.Path(folder)
    (folder / TRUTH_FOLDER).mkdir(parents=True, exist_ok=True)
    programmes = scenario_names(plan.preset)
    rows = []
    for u in range(plan.units):
        raw = machine_instance(plan.preset, plan.seed * 1000 + u)
        env = environment_input_names(load_machine(raw))
        for k in range(plan.runs_per_unit):
            programme = programmes[(k + u) % len(programmes)]
            run_seed = plan.seed * 100000 + 100 * u + k
            timeline = make_timeline(plan.preset, programme, hours=plan.hours, seed=run_seed, step_s=plan.step_s)
            rec = simulate(raw, timeline, seed=run_seed).to_recording()
            rng = np.random.default_rng([plan.seed, u, k, 7])
            cols = {c: (v + rng.normal(0.0, plan.probe_noise_um, v.size) if column_kind(c) == "error" else v)
                    for c, v in rec.columns.items() if c not in env}
            name = f"u{u}_r{k}"
            write_recording_csv(folder / f"{name}.csv", rec.time_s, cols)
            truth = f"{TRUTH_FOLDER}/{name}.csv"
            write_recording_csv(folder / truth, rec.time_s,
                                {c: v for c, v in rec.columns.items() if column_kind(c) == "error"})
            rows.append({"path": f"{name}.csv", "name": name, "unit": f"U{u}", "programme": programme,
                         "date": (FIRST_DAY + datetime.timedelta(days=k)).isoformat(), "truth_path": truth})
    manifest = folder / "manifest.csv"
    with manifest.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return manifest


def load_truth(run: Run) -> dict[str, np.ndarray] | None:
    """The run's noise-free displacements in the run's frame (relative to the recording's first
    finite reading of each channel, the reference its displacements are scored from), or None
    when its manifest names no ``truth_path``."""
    rel = run.entry.extra.get("truth_path")
    if not rel:
        return None
    path = pathlib.Path(run.entry.path).parent / rel
    try:
        truth, rec = read_recording_csv(path), read_recording_csv(run.entry.path)
    except RecordingError as exc:
        raise DatasetError(f"{run.entry.path}: field 'truth_path' = {rel!r}: {exc}") from None
    out = {}
    for c in run.data.channels:
        v, raw = truth.columns.get(c), rec.columns.get(c)
        if v is None or raw is None or v.shape != (len(run.data),) or not np.array_equal(truth.time_s, rec.time_s):
            raise DatasetError(f"{path}: field {c!r}: missing or not on the recording's {len(run.data)} rows and times")
        ok = np.flatnonzero(np.isfinite(raw))
        out[c] = v - (raw[ok[0]] if ok.size else 0.0)
    return out


def unseen_fold(plan: FleetPlan, train_runs_per_unit: int) -> RunFold:
    """Units 0..U-2 train on their first runs; ``validation``: their later runs (unseen runs of
    known units); ``test``: every run of the last unit (an unseen unit). Indices follow
    :func:`write_fleet`'s manifest order."""
    r, last = plan.runs_per_unit, plan.units - 1
    train = tuple(u * r + k for u in range(last) for k in range(train_runs_per_unit))
    unseen_runs = tuple(u * r + k for u in range(last) for k in range(train_runs_per_unit, r))
    unseen_unit = tuple(last * r + k for k in range(r))
    return RunFold(f"{plan.preset}: units U0-U{last - 1} runs 0-{train_runs_per_unit - 1}", train,
                   unseen_runs, unseen_unit)
