"""learn's structural stage: a unit whose chiller follows the hall, or whose hall sensor drifts,
is learned from the cell's probes and temperatures alone; the word is written into the unit
twin, the report says what was added, and the drift reaches what the soft sensors read."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from thermal_eval.learn.bench import cell_view
from thermal_eval.learn.command import learn
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.learn.run import markdown
from thermal_eval.learn.words import candidates
from thermal_twin.machine.instance import machine_instance
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate
from thermal_twin.sim.type_soft_sensors import TypeSoftSensors

HOURS, TRAIN_H, EVERY_H = 60.0, 48.0, 1.0
COMPS = ["E_X0C", "E_Y0C", "E_Z0T", "E_R0T", "E_A0C", "E_B0C", "E_C0C"]


def _learned(spec: dict, tmp_path, seed: int = 3) -> dict:
    machine = load_machine(spec)
    rec = simulate(machine, make_timeline("nmv5000", "talc-178h-dry", hours=HOURS, seed=seed), seed=seed).to_recording()
    rng = np.random.default_rng(seed)
    idx = np.unique(np.searchsorted(rec.time_s, np.arange(0.0, HOURS * 3600.0, EVERY_H * 3600.0)))
    noise = {c: (1.2 if c in ("E_A0C", "E_B0C", "E_C0C") else 0.25) for c in COMPS}
    probes = ProbeSet(rec.time_s[idx], {c: rec.columns[c][idx] - rec.columns[c][0] + rng.normal(0, noise[c], idx.size)
                                         for c in COMPS}, noise, source="test")
    return learn("nmv5000", cell_view(rec, machine), probes, tmp_path / "out", TRAIN_H, build_priors=False)


@pytest.mark.slow
def test_a_chiller_that_follows_the_hall_is_named_and_fitted(tmp_path):
    spec = machine_instance("nmv5000", 3)
    spec["boundaries"]["cooler"] = {"temperature": "ambient_degc"}          # the truth: it follows exactly
    rep = _learned(spec, tmp_path)
    words = rep["structure"]["words"]
    assert words and words[0]["kind"] == "follows" and words[0]["word"] == "cooler follows ambient", words
    assert words[0]["parameters"]["gain"] >= 0.4         # it follows (the calibration keeps part: docs/learn.md)
    md = markdown(rep)                                   # report.md says what was added, from the JSON
    assert f"- {words[0]['what']} (fit cost {words[0]['fit_cost']:.3g}" in md
    unit = load_machine(str(tmp_path / "out" / "unit_twin.yaml"))
    assert unit.boundaries["cooler"].follows is not None and unit.boundaries["cooler"].follows.temperature == "ambient"
    scores = rep["held_out_scores"]
    assert sum(scores["twin (unit), open loop"][c]["rmse"] for c in COMPS[:4]) < \
        0.5 * sum(scores["twin (type), open loop"][c]["rmse"] for c in COMPS[:4]), scores


@pytest.mark.slow
def test_a_drifting_hall_sensor_is_learned_and_read_backwards_by_the_soft_sensors(tmp_path):
    spec = machine_instance("nmv5000", 3)
    spec["sensors"]["ambient"]["bias"] = 0.3
    spec["sensors"]["ambient"]["drift_k_per_h"] = 0.03
    rep = _learned(spec, tmp_path)
    words = {w["kind"]: w for w in rep["structure"]["words"]}
    assert "sensor_drift" in words, rep["structure"]["words"]
    drift = words["sensor_drift"]["parameters"]["drift_K_per_h"]
    assert 0.01 <= drift <= 0.045          # the right sign and size (36 h: part is taken by other parameters)
    unit = load_machine(str(tmp_path / "out" / "unit_twin.yaml"))
    assert unit.sensors["ambient"].drift_k_per_h == pytest.approx(drift)
    soft = TypeSoftSensors(unit)
    soft.update(40 * 3600.0, {"ambient": 23.0}, {})
    b = unit.sensors["ambient"].bias
    assert soft.last_inputs["ambient_degc"] == pytest.approx(23.0 - b - 40.0 * drift)


def test_candidate_words_cover_every_kind_and_stay_valid_twins():
    m = load_machine("nmv5000")
    cal = copy.deepcopy(m.to_dict())
    from thermal_twin.calibrate.bounds import free_parameters        # this test only
    p = next(q for q in free_parameters(cal) if q.name == "links.bed_ambient.conductance")
    words = candidates(m, cal, [(p, p.hi)], {"ambient_degc": 20.0, "coolant_temp_degc": 22.0, "c_speed_rpm": 0.0,
                                             "coolant_on": 0.0})
    kinds = {w.kind for w in words}
    assert kinds == {"beyond_tolerance", "follows", "extra_source", "sensor_drift"}
    for w in words:
        theta = 0.5 * (w.lb + w.ub)
        load_machine(w.spec(cal, theta))                  # every word at mid-range is a valid twin
        assert w.describe(theta)
    beyond = next(w for w in words if w.kind == "beyond_tolerance")
    assert beyond.describe(np.array([np.log(2.0)])).startswith(
        "beyond the builder's tolerance: links.bed_ambient.conductance moved by +100 %")
