"""A fleet made with the twin, as a data set: several units of a preset, several runs each.

Unit u of a preset is :func:`thermal_twin.machine.instance.machine_instance` (its parameters
perturbed within the instance tolerances); run k of a unit is one of the preset's scenarios
(programmes, taken in turn) for ``hours`` with its own seed (so its own hall profile and machine
programme draw), simulated by the twin, with probe noise added to every displacement channel
(normal, ``probe_noise_um``: U(k=2) = 0.4 um of the thesis's probing cycle, Table 5.4). The
hall temperature inputs of the twin (its environment) are left out of the recording: a real
cell measures the hall by a sensor, not by a set-point. Written as recording CSVs plus a
manifest (unit, programme, date) in a folder; deterministic for fixed seeds.
"""
from __future__ import annotations

import csv
import datetime
import pathlib
from dataclasses import dataclass

import numpy as np

from thermal_comp_common.recording_csv import column_kind, write_recording_csv
from thermal_comp_common.run_splits import RunFold
from thermal_twin.machine.instance import machine_instance
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.scenarios import make_timeline, scenario_names
from thermal_twin.sim.simulate import environment_input_names, simulate

PROBE_NOISE_UM = 0.2
FIRST_DAY = datetime.date(2026, 1, 5)


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
    folder.mkdir(parents=True, exist_ok=True)
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
            rows.append({"path": f"{name}.csv", "name": name, "unit": f"U{u}", "programme": programme,
                         "date": (FIRST_DAY + datetime.timedelta(days=k)).isoformat()})
    manifest = folder / "manifest.csv"
    with manifest.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return manifest


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
