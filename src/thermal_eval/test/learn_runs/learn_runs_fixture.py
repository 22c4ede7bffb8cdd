"""Short twin-made runs of one mini-mill unit (two parameters moved beyond the drawing), as a cell
records them: temperatures and inputs (no true hall), probes every half hour with Table 5.4
noise, each run its own programme, hall and probing clock, errors since the run's start."""
from __future__ import annotations

import pathlib

import numpy as np

from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.diagnose.concealed import operating_programme
from thermal_eval.learn.probes import cell_view
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate

TWIN = pathlib.Path(__file__).parents[3] / "thermal_twin" / "test" / "diagnose" / "mini_mill.yaml"
COMPS = ["E_Z0T", "E_X0C"]
HOURS, EVERY_S, NOISE = 6.0, 1800.0, 0.25


def unit_spec() -> dict:
    spec = load_machine(TWIN).to_dict()
    spec["links"]["spindle_head"]["conductance"] *= 1.6
    spec["sources"]["spindle_losses"]["coefficient"] *= 1.4
    return spec


def write_runs(folder: pathlib.Path, n: int, seed0: int = 0, corrupt: dict | None = None) -> list[pathlib.Path]:
    """``n`` runs as recording CSVs (probes in the error columns, empty elsewhere); ``corrupt``:
    run index -> um added to its probes."""
    spec, twin = unit_spec(), load_machine(TWIN)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(n):
        rec = simulate(spec, operating_programme(twin.to_dict(), hours=HOURS, step_s=300.0, seed=seed0 + k),
                       seed=seed0 + k).to_recording()
        rng = np.random.default_rng(100 + seed0 + k)
        cols = dict(cell_view(rec, load_machine(spec)).columns)
        idx = np.searchsorted(rec.time_s, np.arange(EVERY_S / 2, HOURS * 3600.0, EVERY_S))
        for c in COMPS:
            col = np.full(len(rec), np.nan)
            col[idx] = rec.columns[c][idx] - rec.columns[c][0] + rng.normal(0.0, NOISE, idx.size)
            col[idx] += (corrupt or {}).get(k, 0.0)
            cols[c] = col
        paths.append(folder / f"day{k + 1}.csv")
        write_recording_csv(paths[-1], rec.time_s, cols)
    return paths
