"""Scoring against the truth: a twin fleet's noise-free displacements, written apart from its
recordings, score the same compensations without the noise of the reading they are scored
against; the models never read them."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from thermal_comp_common.recording_csv import read_recording_csv, write_recording_csv
from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_eval.datasets import RunFold, load_runs, resolve_runs
from thermal_eval.datasets.evaluate_runs import EvaluationResult, _residuals, evaluate_runs
from thermal_eval.datasets.fleet import TRUTH_FOLDER, FleetPlan, load_truth, write_fleet
from thermal_eval.datasets.report_runs import fleet_markdown
from thermal_eval.datasets.bench_runs import summary, worst_run_ratio
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.run import available_models

HOURLY = ProbingBudget(probe_every_h=1.0, max_probes_per_h=1.0)
FOLD = RunFold("U0 trains", (0, 1), (), (2, 3))
ONE = EngineSpec("local", workers=1)


def _fleet(tmp_path, noise: float):
    plan = FleetPlan("swiss-lathe", units=2, runs_per_unit=2, hours=2.0, probe_noise_um=noise, seed=3)
    runs = load_runs(resolve_runs([str(write_fleet(plan, tmp_path / "fleet"))]))
    return runs, available_models(runs[0].data, ["lagged_ridge"])


def _evaluate(runs, models, truth=None):
    return evaluate_runs(runs, [FOLD], models=models, budget=HOURLY, engine=ONE, truth=truth, progress=lambda s: None)


def _without(obj, keys=("vs_truth", "seconds")):
    """The figures with the truth's and the wall clock's keys left out (what must not change)."""
    if isinstance(obj, dict):
        return {k: _without(v, keys) for k, v in obj.items() if k not in keys}
    if isinstance(obj, list):
        return [_without(v, keys) for v in obj]
    return obj


def test_truth_is_written_apart_and_named_by_the_manifest(tmp_path):
    runs, _ = _fleet(tmp_path, 0.2)
    folder = tmp_path / "fleet"
    assert all(r.entry.extra["truth_path"] == f"{TRUTH_FOLDER}/{r.entry.name}.csv" for r in runs)
    listed = resolve_runs([str(folder)])                                # a folder of runs skips it
    assert listed and not any(pathlib.Path(r.path).parent.name == TRUTH_FOLDER for r in listed)
    truth = read_recording_csv(folder / TRUTH_FOLDER / "u0_r0.csv")
    rec = read_recording_csv(folder / "u0_r0.csv")
    assert set(truth.columns) == set(runs[0].data.channels)          # displacements only: not a recording
    noise = np.concatenate([rec.columns[c] - truth.columns[c] for c in truth.columns])
    assert 0.15 < noise.std() < 0.25 and abs(noise.mean()) < 0.05
    t = load_truth(runs[0])
    c = runs[0].data.channels[0]
    # the run's frame: relative to the recording's first (noisy) reading, as its displacements are
    np.testing.assert_allclose(t[c], truth.columns[c] - rec.columns[c][0])
    np.testing.assert_allclose(runs[0].data.displacement_um[c] - t[c], rec.columns[c] - truth.columns[c])


def test_without_probe_noise_the_truth_scores_as_the_recording(tmp_path):
    runs, models = _fleet(tmp_path, 0.0)
    f = _evaluate(runs, models, [load_truth(r) for r in runs])
    for role, p in f["pooled"].items():
        assert p["vs_truth"] == _without(p, ("vs_truth",)), role
        assert p["adaptive"] and p["open_loop"]
    for r in f["folds"][0]["per_run"]:
        assert r["pooled"]["vs_truth"] == _without(r["pooled"], ("vs_truth",))


def test_the_models_never_read_the_truth(tmp_path):
    """Figures against the recording are bit-identical with the truth, with a false truth and
    with no truth at all (its files deleted); only the scoring against it moves."""
    runs, models = _fleet(tmp_path, 0.2)
    truth = [load_truth(r) for r in runs]
    with_truth = _evaluate(runs, models, truth)
    false = _evaluate(runs, models, [{c: v + 50.0 for c, v in t.items()} for t in truth])
    for p in (tmp_path / "fleet" / TRUTH_FOLDER).iterdir():
        p.unlink()
    again = load_runs(resolve_runs([str(tmp_path / "fleet" / "manifest.csv")]))
    without = _evaluate(again, models)
    assert _without(with_truth) == _without(false) == _without(without)
    assert "vs_truth" not in without["pooled"]["test"]
    t, f = with_truth["pooled"]["test"]["vs_truth"], false["pooled"]["test"]["vs_truth"]
    assert t["adaptive"]["lagged_ridge"] != f["adaptive"]["lagged_ridge"]
    with pytest.raises(Exception, match="truth_path"):
        load_truth(again[0])


def _constant_runs(tmp_path, sigma: float, n_runs: int = 3, hours: float = 40.0):
    """Runs whose displacement does not move: a constant plus a reading error of +-sigma (random
    sign, so that one reading's error is sigma in size exactly); its truth in the run's frame."""
    entries, truth = [], []
    for k in range(n_runs):
        rng = np.random.default_rng(k)
        t = np.arange(0.0, hours * 3600.0, 120.0)
        amb = 20.0 + np.sin(t / 9000.0 + k) + 0.05 * rng.normal(size=t.size)
        noise = sigma * rng.choice([-1.0, 1.0], t.size)
        path = tmp_path / f"const{k}.csv"
        write_recording_csv(path, t, {"amb_c": amb, "z_um": 5.0 + noise}, precision=12)
        truth.append({"z_um": np.full(t.size, -noise[0])})            # 5 - (5 + noise[0])
        entries.append(str(path))
    return load_runs(resolve_runs(entries)), truth


def test_holding_a_constant_against_the_truth_carries_the_held_probes_noise_once(tmp_path):
    sigma = 0.5
    runs, truth = _constant_runs(tmp_path, sigma)
    budget = ProbingBudget(probe_every_h=0.25, max_probes_per_h=4.0)
    f = evaluate_runs(runs, [RunFold("two train", (0, 1), (), (2,))], models=available_models(runs[0].data, []),
                      budget=budget, engine=ONE, truth=truth, progress=lambda s: None)
    p = f["pooled"]["test"]
    for model in p["adaptive"]:
        rec, tru = p["adaptive"][model]["z_um"], p["vs_truth"]["adaptive"][model]["z_um"]
        # against the truth every row is off by the held reading's error: sigma, no more
        assert tru["hold_own_probes_mae_um"] == tru["hold_own_probes_rmse_um"] == tru["hold_own_probes_p99_um"] == sigma
        # against the recording the row's own reading error adds: 0 or 2 sigma, RMS sigma * sqrt(2)
        assert 0.85 * sigma * np.sqrt(2.0) < rec["hold_own_probes_rmse_um"] < 1.15 * sigma * np.sqrt(2.0)
        assert rec["hold_own_probes_p99_um"] == 2 * sigma


def test_residuals_against_the_truth_are_the_recordings_plus_the_gap():
    """Holding a probe of a constant: against the recording n(t) - n(t_k), against the truth -n(t_k)."""
    rng = np.random.default_rng(1)
    n = rng.normal(0.0, 0.2, 40)
    y = {"z_um": n - n[0]}
    truth = {"z_um": np.full(40, -n[0])}
    probes = np.arange(40) // 10 * 10                                  # probe every 10 rows, held
    held = y["z_um"][probes]
    res = EvaluationResult({}, {"m": {"z_um": np.zeros(40)}}, {"m": {"z_um": held}}, {"m": {"z_um": held}})
    r = _residuals(res, y, slice(1, 40), truth)
    np.testing.assert_allclose(r["hold"]["m"]["z_um"], (n - n[probes])[1:])
    np.testing.assert_allclose(r["truth"]["hold"]["m"]["z_um"], -n[probes][1:])
    np.testing.assert_allclose(r["truth"]["open_loop"]["m"]["z_um"], np.full(39, -n[0]))
    assert "truth" not in _residuals(res, y, slice(1, 40))


def test_fleet_table_shows_both_scorings(tmp_path):
    runs, models = _fleet(tmp_path, 0.2)
    f = _evaluate(runs, models, [load_truth(r) for r in runs])
    fig = {"plan": {"units": 2, "runs_per_unit": 2, "hours": 2.0, "probe_noise_um": 0.2}, "run_start": f["run_start"],
           "seconds": f["seconds"], "unseen_unit": summary(f["pooled"]["test"], "static_ls"),
           "unseen_runs": summary(f["pooled"]["test"], "static_ls"), "evaluation": f,
           "worst_run_ratio_to_hold": worst_run_ratio(f), "worst_run_ratio_to_hold_vs_truth": worst_run_ratio(f, True)}
    text = fleet_markdown("swiss-lathe", fig, 3)
    header = text.splitlines()[2]
    assert "| worst channel x hold (runs / unit) |" in header and "vs truth: worst channel x hold (runs / unit)" in header
    row = next(x for x in text.splitlines() if x.startswith("| `lagged_ridge`"))
    tr = fig["unseen_unit"]["vs_truth"]["adaptive"]["lagged_ridge"]["worst_channel_ratio_to_hold"]
    assert row.count("|") == header.count("|") and f"{tr:.3f}" in row.split("|")[-3]
