"""Rows a recording dropped: the twin steps through them with interpolated inputs instead of
holding the last recorded row's inputs across the gap; regular grids are untouched."""
from __future__ import annotations

import pathlib

import numpy as np

from thermal_eval.diagnose.concealed import operating_programme
from thermal_twin.diagnose.fit import noise_free
from thermal_twin.diagnose.twin_eval import expected_outputs, gap_envelope, gap_filled, node_states
from thermal_twin.diagnose import twin_eval
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.sim.simulate import simulate

HERE = pathlib.Path(__file__).parent
MACHINE = load_machine(noise_free(load_machine(HERE / "mini_mill.yaml").to_dict()))


def _programme(hours: float = 30.0, step: float = 300.0):
    tl = operating_programme(MACHINE.to_dict(), hours, step, seed=3)
    return tl.time_s, tl.resolved(MACHINE)


def test_regular_and_jittered_grids_take_the_held_path_bit_for_bit():
    t, vals = _programme()
    jittered = t + np.random.default_rng(0).uniform(-1e-3, 1e-3, t.size) * (t > 0)
    for grid in (t, jittered):
        assert gap_filled(grid, vals) is None
        _, _, X, tb = node_states(MACHINE, grid, vals)
        _, _, X_held, tb_held = twin_eval._held_states(MACHINE, grid, vals)
        assert np.array_equal(X, X_held) and np.array_equal(tb, tb_held)


def test_filled_grid_puts_the_missing_instants_back_with_interpolated_inputs():
    t = np.array([0.0, 60.0, 240.0, 300.0, 360.0])          # two rows missing after 60 s
    filled = gap_filled(t, {"u": np.array([1.0, 1.0, 4.0, 4.0, 5.0])})
    assert filled is not None
    t_new, vals, rows = filled
    assert np.allclose(t_new, [0, 60, 120, 180, 240, 300, 360])
    assert np.allclose(vals["u"], [1, 1, 2, 3, 4, 4, 5])
    assert np.array_equal(t_new[rows], t)


def test_states_across_a_gap_match_the_full_grid_where_the_inputs_are_ramps():
    """An input sampled from a ramp is recovered exactly by the interpolation, so the node
    temperatures at the kept rows equal those of the full recording."""
    t = np.arange(0.0, 24 * 3600.0 + 1.0, 300.0)
    vals = {k: np.full(t.size, MACHINE.inputs[k].default) for k in MACHINE.inputs}
    amb = next(k for k in MACHINE.inputs if "ambient" in k)
    vals[amb] = 20.0 + 2.0 * t / t[-1]
    keep = np.ones(t.size, bool)
    keep[5:40:3] = False
    keep[100:104] = False
    _, _, X_full, _ = node_states(MACHINE, t, vals)
    _, _, X_kept, _ = node_states(MACHINE, t[keep], {k: v[keep] for k, v in vals.items()})
    assert np.max(np.abs(X_kept - X_full[keep])) < 1e-9 * np.ptp(X_full)


def test_dropped_rows_at_input_switches_cost_less_than_holding_the_last_row():
    """The true machine runs on the full grid; the recording lost every row at which the
    spindle switched and a few around it. Holding the last recorded row (what ``simulate``
    does with the kept rows as its time line) applies each switch a whole gap late; the
    interpolated inputs meet the switch half-way on average."""
    t, vals = _programme()
    truth = expected_outputs(MACHINE, t, vals)
    speed = next(k for k in MACHINE.inputs if "rpm" in k)
    switches = np.flatnonzero(np.diff(vals[speed]) != 0) + 1
    assert switches.size >= 4
    keep = np.ones(t.size, bool)
    keep[switches] = False
    keep[switches[::2] - 1] = False                       # some gaps of two rows
    keep[0] = keep[-1] = True
    kept = {k: v[keep] for k, v in vals.items()}
    filled = expected_outputs(MACHINE, t[keep], kept)
    held = simulate(MACHINE, InputsTimeline(t[keep], kept)).columns()

    def rms(out):
        return np.sqrt(np.mean([np.mean((out[c] - truth[c][keep]) ** 2) for c in truth]))
    assert rms(filled) < 0.6 * rms(held)


def test_the_envelope_of_the_unknown_switch_instant_bounds_the_filled_twin_error():
    """Where no input changes across a gap the instant does not matter (zero envelope); after
    a gap hiding a spindle switch the twin's error with interpolated inputs stays within the
    envelope between the switch at the gap's first missing instant and at its end, summed
    over the gaps."""
    t, vals = _programme()
    assert gap_envelope(MACHINE, t, vals) is None
    truth = expected_outputs(MACHINE, t, vals)
    speed = next(k for k in MACHINE.inputs if "rpm" in k)
    switches = np.flatnonzero(np.diff(vals[speed]) != 0) + 1
    keep = np.ones(t.size, bool)
    keep[switches] = False
    quiet = np.flatnonzero(np.all([np.diff(v) == 0 for v in vals.values()], axis=0))
    keep[quiet[quiet > 1][::10]] = False                 # gaps across which nothing changes
    keep[0] = keep[-1] = True
    kept = {k: v[keep] for k, v in vals.items()}
    env = gap_envelope(MACHINE, t[keep], kept)
    filled = expected_outputs(MACHINE, t[keep], kept)
    first_switch_row = int(np.searchsorted(t[keep], t[switches[0]]))
    for c in truth:
        assert np.all(env[c][:first_switch_row] < 1e-9 * max(1.0, np.ptp(truth[c])))
        # within 1 % of the largest envelope: the gaps' effects add up only approximately
        # where conductances depend on the speed
        assert np.all(np.abs(filled[c] - truth[c][keep]) <= env[c] + 0.01 * np.max(env[c])), c
    assert max(float(np.max(e)) for e in env.values()) > 0.01
