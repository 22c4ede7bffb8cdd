"""machine_sim's checkpoint writes two slots in turn: a save cut short leaves the previous
instant readable, and a restarted writer goes on in the slot after the one it loaded."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.scenario_runner import ScenarioRunner
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.checkpoint import TwinCheckpoint

KEY = {"machine": "nmv5000", "scenario": "talc-178h-dry", "seed": 3, "hours": 4.0, "step_s": 300.0,
       "probe_noise": True}


def _runner():
    m = load_machine("nmv5000")
    return ScenarioRunner(m, make_timeline(m.name, "talc-178h-dry", hours=4.0, seed=3, step_s=300.0), seed=3)


def _saved(tmp_path, steps: int):
    r, cp = _runner(), TwinCheckpoint(str(tmp_path / "twin.pkl"), KEY, fsync=False)
    for _ in range(steps):
        cp.save(r, np.random.default_rng(1), {"X": float(r.k)})
        r.step()
    return cp


def test_the_newest_save_is_loaded(tmp_path):
    _saved(tmp_path, 5)
    runner, _, offsets = TwinCheckpoint(str(tmp_path / "twin.pkl"), KEY).load()
    assert runner.k == 4 and offsets == {"X": 4.0}


def test_a_save_cut_short_leaves_the_previous_instant(tmp_path):
    cp = _saved(tmp_path, 5)                  # last save (instant 4) went to slot 4 % 2 = 0
    path = tmp_path / "twin.pkl"
    data = bytearray(path.read_bytes())
    data[100:110] = b"\xff" * 10               # slot 0's payload damaged mid-write
    path.write_bytes(bytes(data))
    runner, _, offsets = TwinCheckpoint(str(path), KEY).load()
    assert runner.k == 3 and offsets == {"X": 3.0}
    assert cp.path == path


def test_a_resumed_writer_goes_on_in_the_other_slot(tmp_path):
    _saved(tmp_path, 3)
    path = str(tmp_path / "twin.pkl")
    cp = TwinCheckpoint(path, KEY, fsync=False)
    runner, rng, _ = cp.load()
    runner.step()
    cp.save(runner, rng, {"X": 99.0})
    again, _, offsets = TwinCheckpoint(path, KEY).load()
    assert again.k == runner.k and offsets == {"X": 99.0}


def test_no_intact_slot_is_refused_in_one_line(tmp_path):
    _saved(tmp_path, 2)
    path = tmp_path / "twin.pkl"
    path.write_bytes(b"\0" * len(path.read_bytes()))
    with pytest.raises(ValueError, match="state_path.*not a readable twin checkpoint") as err:
        TwinCheckpoint(str(path), KEY).load()
    assert "\n" not in str(err.value)


def test_rebuilt_parts_are_saved_by_name_and_taken_from_the_loader(tmp_path):
    from thermal_twin.sim.checkpoint import shared_objects
    a, path = _runner(), str(tmp_path / "twin.pkl")
    a.step()
    TwinCheckpoint(path, KEY, shared=shared_objects(a)).save(a, None, {})
    fresh = _runner()
    b, _, _ = TwinCheckpoint(path, KEY, shared=shared_objects(fresh)).load()
    assert b.timeline is fresh.timeline and b.machine is fresh.machine and b.k == a.k
    assert b.stepper.net is fresh.stepper.net and b.stepper.x is not fresh.stepper.x
    b.step()
    a.step()
    assert a.errors() == b.errors()
    with pytest.raises(ValueError, match="not a readable twin checkpoint"):
        TwinCheckpoint(path, KEY).load()       # a loader without the shared parts
