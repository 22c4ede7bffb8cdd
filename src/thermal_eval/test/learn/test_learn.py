"""thermal-comp learn: a unit whose twin lacks a heat source is learned from its probes alone
(sparse, noisy; no ground truth, no true hall), the learned twin predicts the held-out probes
better than the type's twin, and what cannot be learned honestly is refused in one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.learn.bench import cell_view
from thermal_eval.learn.cli import main as learn_main
from thermal_eval.learn.probe_score import hold_last, score_table, static_regression, training_mean
from thermal_eval.learn.probes import ProbeDataError, ProbeSet, cell_recording
from thermal_eval.learn.unit_fit import LearnError, learn_unit_twin
from thermal_eval.learn.units import KINDS, structural_unit
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

HOURS, TRAIN_H, EVERY_H = 36.0, 24.0, 1.0
COMPS = ["E_X0C", "E_Y0C", "E_Z0T"]


@pytest.fixture(scope="module")
def unit_run():
    unit = structural_unit("extra_source", 3)
    rec = simulate(unit.machine, make_timeline("nmv5000", "talc-178h-dry", hours=HOURS, seed=3), seed=3).to_recording()
    rng = np.random.default_rng(0)
    idx = np.unique(np.searchsorted(rec.time_s, np.arange(0.0, HOURS * 3600.0, EVERY_H * 3600.0)))
    probes = ProbeSet(rec.time_s[idx], {c: rec.columns[c][idx] - rec.columns[c][0] + rng.normal(0, 0.25, idx.size)
                                         for c in COMPS}, {c: 0.25 for c in COMPS}, source="test")
    return unit, rec, probes


def test_a_cell_view_hides_the_truth_and_the_true_hall(unit_run):
    unit, rec, _ = unit_run
    cell = cell_view(rec, unit.machine)
    assert not cell.errors and "ambient_degc" not in cell.columns and "ambient_c" in cell.columns


def test_the_learned_twin_predicts_held_out_probes_better(unit_run):
    unit, rec, probes = unit_run
    fit = learn_unit_twin("nmv5000", cell_view(rec, unit.machine), probes, TRAIN_H * 3600.0)
    assert fit.components == COMPS and fit.probes_train == 25 and fit.probes_held_out == 11
    cal = fit.calibration
    idx = np.searchsorted(cal.time_s, probes.time_s)
    held = probes.time_s > TRAIN_H * 3600.0
    before = {c: np.asarray(cal.before[c])[idx] for c in COMPS}
    after = {c: np.asarray(cal.after[c])[idx] for c in COMPS}
    table = score_table(probes, {"type": before, "unit": after, "hold": hold_last(probes),
                                 "mean": training_mean(probes, TRAIN_H * 3600.0)}, held)
    total_type = sum(table["type"][c]["rmse"] for c in COMPS)
    total_unit = sum(table["unit"][c]["rmse"] for c in COMPS)
    assert total_unit < 0.5 * total_type, table        # the missing source is learned
    # no channel worse by more than twice the probe noise (E_X0C, ~1 um, loses about 0.3 um here)
    assert all(table["unit"][c]["rmse"] <= table["type"][c]["rmse"] + 2 * 0.25 for c in COMPS), table
    assert all(table["mean"][c]["n"] == 11 for c in COMPS)


def test_probe_baselines_are_computed_before_each_probe():
    t = np.arange(5) * 3600.0
    p = ProbeSet(t, {"E_X0C": np.array([0.0, 1.0, 2.0, 3.0, 4.0])}, {"E_X0C": 0.25})
    assert np.isnan(hold_last(p)["E_X0C"][0]) and list(hold_last(p)["E_X0C"][1:]) == [0.0, 1.0, 2.0, 3.0]
    assert training_mean(p, 2 * 3600.0)["E_X0C"][4] == pytest.approx(1.0)


def test_bad_probe_sets_are_named():
    with pytest.raises(ProbeDataError, match="instants must increase"):
        ProbeSet(np.array([0.0, 0.0]), {"E_X0C": np.zeros(2)}, {"E_X0C": 0.25})
    with pytest.raises(ProbeDataError, match=r"'E_X0C' at t = 3600 s is inf"):
        ProbeSet(np.array([0.0, 3600.0]), {"E_X0C": np.array([0.0, np.inf])}, {"E_X0C": 0.25})
    with pytest.raises(ProbeDataError, match="noise of 'E_X0C' is 0.0"):
        ProbeSet(np.array([0.0]), {"E_X0C": np.zeros(1)}, {"E_X0C": 0.0})


def test_too_few_training_probes_are_refused(unit_run):
    unit, rec, probes = unit_run
    with pytest.raises(LearnError, match=r"only 3 probes of 'E_X0C' up to t = 2.0 h, need at least 4"):
        learn_unit_twin("nmv5000", cell_view(rec, unit.machine), probes, 2.0 * 3600.0)


def test_every_unit_kind_is_a_valid_twin_that_differs_from_the_type():
    for kind in KINDS:
        unit = structural_unit(kind, 5)
        assert unit.truth and unit.machine.name == "nmv5000"
        assert structural_unit(kind, 5).truth == unit.truth          # a seed is one unit


def _csv(unit_run, tmp_path):
    """The cell as a recording CSV: temperatures, machine inputs, probes in the error columns."""
    unit, rec, probes = unit_run
    cell = cell_view(rec, unit.machine)
    cols = dict(cell.columns)
    for c in COMPS:
        col = np.full(len(cell), np.nan)
        col[np.searchsorted(cell.time_s, probes.time_s)] = probes.values[c]
        cols[c] = col
    path = tmp_path / "cell.csv"
    write_recording_csv(path, cell.time_s, cols)
    return path


def test_cli_writes_the_unit_twin_and_a_report_generated_from_its_json(unit_run, tmp_path, capsys):
    path = _csv(unit_run, tmp_path)
    rec, probes = cell_recording(path)
    assert not rec.errors and sorted(probes.values) == sorted(COMPS)
    out = tmp_path / "out"
    assert learn_main([str(path), "--twin", "nmv5000", "--out", str(out), "--train-h", str(TRAIN_H),
                       "--no-prior", "--quiet"]) == 0
    rep = json.loads((out / "report.json").read_text())
    md = (out / "report.md").read_text()
    assert (out / "unit_twin.yaml").is_file()
    assert (rep["probes"]["train"], rep["probes"]["validation"], rep["probes"]["held_out"]) == (19, 6, 11)
    assert rep["adoption"]["adopt"] and f"**Adopted**: {rep['adoption']['reason']}." in md
    for name, row in rep["held_out_scores"].items():      # every RMSE in the md is the JSON's
        assert f"| {name} | " + " | ".join(f"{row[c]['rmse']:.3g}" for c in COMPS) + " |" in md
    assert learn_main([str(path), "--twin", "nmv5000", "--out", str(out), "--no-prior", "--quiet"]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    assert learn_main([str(path), "--twin", "nmv5000", "--out", str(tmp_path / "o2"), "--train-h", "35.9",
                       "--validate-h", "0", "--no-prior", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("thermal-comp learn: --train-h 35.9: leaves") and "\n" not in err


def test_a_bag_gives_measured_plus_the_offsets_the_bridge_held(tmp_path):
    """errors/measured holds residuals on a compensated machine; the total error adds what the
    bridge reported holding at the probe (axis offsets seen by the probe as a table shift)."""
    from thermal_comp_common.bags import msg_definitions                    # this test only
    from thermal_comp_common.bags.csv_to_bag import recording_to_bag          # this test only
    from thermal_comp_common.bags.writer import BagWriter, TopicInfo          # this test only
    from thermal_comp_common.recording_csv import Recording                   # this test only
    from thermal_eval.learn.probes import _applied_at                         # this test only
    t = np.arange(6) * 300.0
    meas = np.full(6, np.nan)
    meas[[1, 4]] = [0.5, -0.25]
    rec = Recording(t, {"ambient_c": np.full(6, 20.0), "c_speed_rpm": np.zeros(6), "E_X0C": meas})
    recording_to_bag(rec, tmp_path / "bag", errors_as="measured")
    got, probes = cell_recording(tmp_path / "bag")
    assert not got.errors and list(probes.time_s) == [300.0, 1200.0]
    assert list(probes.values["E_X0C"]) == [0.5, -0.25]         # no offsets recorded: nothing added
    store = msg_definitions.typestore()
    T = "thermal_comp_msgs/msg/AxisOffsets"
    Msg, Header, Time = store.types[T], store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    with BagWriter(tmp_path / "offsets", [TopicInfo("/offsets", T)]) as bag:
        for stamp, x, on in ((300, 3.0, True), (900, 4.0, False)):
            msg = Msg(header=Header(stamp=Time(sec=stamp, nanosec=0), frame_id=""), axis_names=["X", "Y", "Z"],
                      commanded_offsets_um=np.array([x, 0.0, 0.0]), applied_offsets_um=np.array([x, 0.0, 0.0]),
                      applied=np.array([True] * 3), limits_hit=np.zeros(3, np.uint8), compensation_enabled=on)
            bag.write("/offsets", stamp * 10**9, store.serialize_cdr(msg, T))
    applied = _applied_at(tmp_path / "offsets", np.array([0.0, 300.0, 1200.0]), ["E_X0C", "E_A0C"], np.zeros(3))
    assert applied.tolist() == [[0.0, 0.0], [3.0, 0.0], [0.0, 0.0]]    # before any, held, compensation off


def test_adoption_needs_better_validation_probes_and_no_component_clearly_worse():
    from thermal_eval.learn.adoption import decide                  # this test only
    v = {"a": np.array([0.0, 1.0, 2.0, 3.0]), "b": np.array([0.0, 0.0, 0.0, 0.0])}
    noise = {"a": 0.25, "b": 0.25}
    mask = np.array([False, True, True, True])
    good = decide(v, noise, {"a": v["a"] + 1.0, "b": v["b"]}, {"a": v["a"] + 0.1, "b": v["b"] + 0.1}, mask)
    assert good.adopt and good.probes == 3
    worse_b = decide(v, noise, {"a": v["a"] + 1.0, "b": v["b"]}, {"a": v["a"], "b": v["b"] + 0.3}, mask)
    assert not worse_b.adopt and "worse beyond the probe uncertainty on b 0.00 -> 0.30" in worse_b.reason
    same = decide(v, noise, v, v, mask)
    assert not same.adopt and "not better" in same.reason
    few = decide(v, noise, v, v, np.array([False, False, True, True]))
    assert not few.adopt and "only 2 validation probes" in few.reason


@pytest.mark.slow
def test_a_second_learning_is_tested_against_the_adopted_prior(unit_run, tmp_path):
    """As the online learner does after an adoption: learn again from the adopted twin with
    --current-prior/--current-config the adopted prior; the adaptive test and the report are
    against that prior, not the type's."""
    path = _csv(unit_run, tmp_path)
    first = tmp_path / "first"
    assert learn_main([str(path), "--twin", "nmv5000", "--out", str(first), "--train-h", str(TRAIN_H), "--quiet"]) == 0
    rep1 = json.loads((first / "report.json").read_text())
    assert rep1["adoption"]["adopt"] and rep1["tested_against"]["source"] == "type"
    second = tmp_path / "second"
    assert learn_main([str(path), "--twin", rep1["files"]["unit_twin"], "--out", str(second), "--train-h", str(TRAIN_H),
                       "--current-prior", rep1["files"]["prior"], "--current-config", rep1["files"]["model_config"],
                       "--quiet"]) == 0
    rep2 = json.loads((second / "report.json").read_text())
    sha = json.loads((first / "prior.json").read_text())["sha256"]
    assert rep2["tested_against"] == {"prior": rep1["files"]["prior"], "sha256": sha, "source": "given",
                                      "model_config": rep1["files"]["model_config"],
                                      "type_model": str((first / "unit_twin.yaml").resolve())}
    assert "adaptive, current prior" in rep2["held_out_scores"] and "adaptive, type prior" not in rep2["held_out_scores"]
    assert f"`{rep1['files']['prior']}` (sha256 {sha}" in (second / "report.md").read_text()
