"""The heat estimated for a missing input goes where the temperatures point: a recording
whose speed also heats the table (a source the twin lacks) gets part of the heat located on
the table, not all of it on the twin's only speed-driven source, and the equivalent speed
is found from the share on the twin's own source."""
from __future__ import annotations

import copy
import pathlib

import numpy as np
import pytest

from thermal_twin.calibrate.input_estimation import estimate_input, fill_missing_inputs
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate
from thermal_eval.diagnose.concealed import operating_programme

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"
TABLE_W = 150.0          # the truth's table source at the maximum speed (the twin has none)


@pytest.fixture(scope="module")
def case():
    twin = load_machine(TWIN)
    spec = copy.deepcopy(twin.to_dict())
    spec["sources"]["table_heat"] = {"node": "table", "input": "spindle_rpm",
                                     "coefficient": TABLE_W / 12000.0 ** 1.5, "exponent": 1.5}
    truth = load_machine(spec)
    rec = simulate(truth, operating_programme(spec, 36.0, 300.0, seed=5), seed=1).to_recording()
    speed = rec.columns.pop("spindle_rpm")
    chans = [c for c in rec.columns if c.endswith("_c") or c.startswith("E_")]
    return twin, rec, speed, chans


def test_the_heat_is_located_on_the_table_too_and_the_speed_follows_the_twins_share(case):
    twin, rec, speed, chans = case
    est = estimate_input(twin, rec, "spindle_rpm", chans, block_s=1800.0)
    # both sources have the same exponent, so the truth's split is 200 : 150 at every speed
    assert set(est.located) == {"spindle", "table"}, est.located
    assert est.located["table"] == pytest.approx(150.0 / 350.0, abs=0.1), est.located
    assert est.own_share == pytest.approx(est.located["spindle"])
    e = est.block_edges_s
    u_true = np.array([speed[(rec.time_s >= a) & (rec.time_s < b)].mean() for a, b in zip(e[:-1], e[1:])])
    run = u_true > 0.5 * u_true.max()
    assert np.median(np.abs(est.equivalent_input[run] - u_true[run]) / u_true[run]) < 0.15
    # without locating, all the heat goes on the spindle source and the speed comes out too high
    flat = estimate_input(twin, rec, "spindle_rpm", chans, block_s=1800.0, locate=False)
    assert np.median(flat.equivalent_input[run] / u_true[run]) > 1.15


def test_the_finding_names_where_the_heat_was_located(case):
    twin, rec, _, chans = case
    _, _, notes = fill_missing_inputs(twin, rec, chans)
    assert "located by the temperatures on" in notes[0] and "table" in notes[0], notes
