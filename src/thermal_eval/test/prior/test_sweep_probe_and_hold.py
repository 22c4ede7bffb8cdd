"""Probe-and-hold at each sweep combination's Q_prod (sweep, sweep_cli, bench models)."""
import csv
import json
import math

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION
from thermal_comp_common.probe_and_hold import probe_and_hold
from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.replay.summary import probe_noise
from thermal_eval.sweep.grid import SweepPoint, SweepRun, evaluate_point, format_probe_and_hold, write_table
from thermal_eval.sweep.cli import main as sweep_main
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

BASE = {"input_names": ["ambient", "ws_mwf", "c_coolant_delta"], "na_max": 1, "nb_max": 3, "nb_max_final": 3}


def _rec(hours=16.0):
    return simulate("nmv5000", make_timeline("nmv5000", "load-case-B", hours=hours, seed=4, step_s=300.0),
                    seed=4)


def test_row_carries_probe_and_hold_at_its_q_prod():
    rec = _rec().to_recording()
    run = SweepRun("talc", BASE, 0.25, 1.2, 0.25, 0, "test")
    row = evaluate_point(rec, run, SweepPoint(8.5, 1.0, 10.0, 6.0, 24.0))
    b = row["probe_and_hold"]
    assert 50.0 < row["q_prod_pct"] < 100.0       # a short run: mostly CP
    # recomputed independently: same Q_prod, noise, resolution, seed and the compensation instants
    from thermal_eval.replay.summary import build_model
    from thermal_eval.replay.virtual_experiment import run_virtual_experiment
    model = build_model("talc", {**BASE, **SweepPoint(8.5, 1.0, 10.0, 6.0, 24.0).config()})
    noise = probe_noise(model.component_names, 0.25, 1.2)
    res = run_virtual_experiment(rec, model, probe_noise_um=noise, probe_resolution_um=0.25, seed=0,
                                 compute_metrics=False)
    mask = np.asarray(res.phase) != PHASE_CALIBRATION
    ref = probe_and_hold(res.time_s, {c: np.asarray(res.true[c], float) for c in res.components},
                         row["q_prod_pct"], noise, 0.25, window=mask, seed=0)
    assert b["p99_lin_um"] == ref["p99_lin_um"]
    assert b["p99_lin_ratio"] == row["p99_lin_um"] / ref["p99_lin_um"]
    assert math.isfinite(b["whole_run_p99_lin_um"]) and b["whole_run_model_p99_lin_um"] >= row["p99_lin_um"] * 0.5
    assert "probe-and-hold at the same Q_prod" in format_probe_and_hold(row)
    assert "n/a" in format_probe_and_hold({"q_prod_pct": 97.0})          # an old results line


def test_table_and_cli_print_the_baseline(tmp_path, capsys):
    r = _rec(12.0)
    write_recording_csv(tmp_path / "rec.csv", r.time_s, r.columns())
    rc = sweep_main([str(tmp_path / "rec.csv"), "--out", str(tmp_path / "out"), "--jobs", "1", "--no-progress",
                     "--grid-subset", "cp_length_h=8.5;post_cp_interval_h=1;ng_interval_min=10;ng_measurements=6",
                     "--set", "na_max=1", "--set", "nb_max=3", "--set", "nb_max_final=3", "--q-prod-min", "50"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "probe-and-hold at the same Q_prod" in out
    with (tmp_path / "out" / "table.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    best = json.loads((tmp_path / "out" / "best.json").read_text())["best"]
    assert math.isclose(float(rows[0]["probe_and_hold_p99_lin_um"]), best["probe_and_hold"]["p99_lin_um"],
                        rel_tol=1e-5)     # the table keeps 6 significant digits
    write_table([], tmp_path / "empty.csv")                                # no rows: header only
