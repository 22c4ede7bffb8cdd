"""bench learn --runs: the unit's daily runs are what a cell records, each on its own probing
clock; the summary scales every component by holding's RMSE."""
from __future__ import annotations

import numpy as np

from thermal_eval.learn.runs import cell_runs
from thermal_eval.learn.runs.bench import DAYS, UNSEEN, summary_markdown, unit_runs


def test_daily_runs_are_a_cells_view_each_with_its_own_probing_clock(tmp_path):
    paths = unit_runs("gain", 5, tmp_path)
    runs = cell_runs(paths)
    assert len(runs) == DAYS + UNSEEN and all("ambient_degc" not in r.rec.columns for r in runs)
    firsts = {round(float(r.probes.time_s[0])) for r in runs}
    assert len(firsts) == len(runs)                              # each run its own clock
    v = runs[0].probes.values["E_X0C"]
    assert np.allclose(v / 0.25, np.round(v / 0.25))             # the probe's resolution
    assert not np.allclose(runs[0].rec.columns["ambient_c"], runs[1].rec.columns["ambient_c"])


def test_the_summary_scales_each_component_by_holding():
    case = {"seed": 1, "kind": "gain", "truth": "t", "adopted": {"first run": True, "3 runs": False},
            "rmse": {"hold last probe": {"E_X0C": 1.0, "E_A0C": 2.0},
                     "twin (type), open loop": {"E_X0C": 0.5, "E_A0C": 2.0}}}
    md = summary_markdown([case])
    assert "| #1 gain | t | yes / no | 1.00 / 1.00 | 0.75 / 0.50 | - |" in md
