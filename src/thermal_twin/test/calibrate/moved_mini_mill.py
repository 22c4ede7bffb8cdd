"""The mini mill with two parameters moved beyond the drawing (the truth calibrate must find) and
runs of it, for the several-run calibration tests."""
from __future__ import annotations

import pathlib

from thermal_eval.diagnose.concealed import operating_programme
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"
HEAD = ("links", "spindle_head", "conductance")
LOSSES = ("sources", "spindle_losses", "coefficient")
TRUE = {HEAD: 8.0 * 1.6, LOSSES: 0.00015396 * 1.4}
# the structure's conductances and the spindle's loss law move; the rest is the drawing's
SECTION = {"kinds": {"capacity": "fixed", "bias": "fixed", "boundary": "fixed", "gain": "fixed",
                     "conductance": {"factor": 2.0}, "source": {"factor": 2.0}}}


def moved_runs(n: int, hours: float, first_programme_seed: int) -> list:
    """``n`` runs of the moved twin, each its own seeded programme and hall, each from rest."""
    spec = load_machine(TWIN).to_dict()
    true = load_machine(TWIN).to_dict()
    for (a, b, c), v in TRUE.items():
        true[a][b][c] = v
    return [simulate(true, operating_programme(spec, hours=hours, step_s=300.0, seed=first_programme_seed + k),
                     seed=k).to_recording() for k in range(n)]
