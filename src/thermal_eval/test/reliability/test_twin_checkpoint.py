"""The twin's checkpoint (machine_sim ``state_path``): a restart goes on exactly where the
twin was; a checkpoint of another configuration or a damaged one is refused, naming why."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_twin.machine.schema import load_machine
from thermal_twin.machine_sim_node import TwinCheckpoint
from thermal_twin.sim.scenario_runner import ScenarioRunner
from thermal_twin.sim.scenarios import make_timeline

KEY = {"machine": "nmv5000", "scenario": "talc-178h-dry", "seed": 3, "hours": 4.0, "step_s": 300.0,
       "probe_noise": True}


def _runner():
    m = load_machine("nmv5000")
    return ScenarioRunner(m, make_timeline(m.name, "talc-178h-dry", hours=4.0, seed=3, step_s=300.0), seed=3)


def test_a_resumed_twin_continues_exactly(tmp_path):
    a = _runner()
    for _ in range(7):
        a.step()
    a.idle(95.0)          # a probing pause moved simulated time on
    a.resume()
    rng = np.random.default_rng([3, 7])
    cp = TwinCheckpoint(str(tmp_path / "twin.pkl"), KEY)
    cp.save(a, rng, {"X": 1.5})
    b, rng_b, offsets = TwinCheckpoint(str(tmp_path / "twin.pkl"), KEY).load()
    assert (b.t_s, b.k, offsets) == (a.t_s, a.k, {"X": 1.5})
    assert rng_b.random() == rng.random()
    for _ in range(5):
        a.step()
        b.step()
        assert a.errors() == b.errors() and a.sensor_readings() == b.sensor_readings()
    assert not (tmp_path / "twin.pkl.tmp").exists()     # written atomically (rename)


def test_no_checkpoint_means_a_fresh_start(tmp_path):
    assert TwinCheckpoint(str(tmp_path / "none.pkl"), KEY).load() is None


def test_a_checkpoint_of_another_configuration_is_refused(tmp_path):
    TwinCheckpoint(str(tmp_path / "t.pkl"), KEY).save(_runner(), None, {})
    with pytest.raises(ValueError, match=r"state_path.*seed=3, this node has seed=4"):
        TwinCheckpoint(str(tmp_path / "t.pkl"), {**KEY, "seed": 4}).load()


def test_a_damaged_checkpoint_is_refused_in_one_line(tmp_path):
    p = tmp_path / "t.pkl"
    TwinCheckpoint(str(p), KEY).save(_runner(), None, {})
    p.write_bytes(p.read_bytes()[:100])
    with pytest.raises(ValueError, match="state_path.*not a readable twin checkpoint") as err:
        TwinCheckpoint(str(p), KEY).load()
    assert "\n" not in str(err.value)
