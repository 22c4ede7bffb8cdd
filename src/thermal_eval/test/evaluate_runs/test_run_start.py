"""How runs start, decided from the data: one recording cut into segments continues from run to
run; runs of different days jump, and are then taken from their own start."""
from __future__ import annotations

import json

import numpy as np
import pytest

from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.datasets import DatasetError, RunFold, load_runs, resolve_runs, segments
from thermal_eval.datasets.evaluate_runs import evaluate_runs
from thermal_eval.datasets.run_start import CONTINUED_BELOW, SEPARATE_REST_H, decide_run_start, start_jumps
from thermal_eval.evaluate.baselines import BASELINES
from thermal_eval.evaluate.cli import main

STATIC = next(m for m in BASELINES if m.name == "static_ls")


def _day(path, seed: int, hours: float = 5.0):
    """A machine that stood overnight: it starts in equilibrium with the hall of that day (another
    temperature each day), heats while it runs; its displacement follows its temperature change
    (one sensor on the machine)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 120.0)
    hall = 17.0 + 2.0 * seed + 0.5 * np.sin(t / 9000.0)
    heat = 6.0 * (1.0 - np.exp(-t / 5400.0))
    machine = hall + heat
    z = 2.5 * (machine - machine[0]) + 0.05 * rng.normal(size=t.size)
    write_recording_csv(path, t, {"machine_c": machine, "z_um": z})
    return path


@pytest.fixture()
def days(tmp_path):
    for k in range(5):
        _day(tmp_path / f"day{k}.csv", k)
    return tmp_path


def test_runs_of_different_days_are_separate_and_one_recording_cut_is_continued(days):
    runs = load_runs(resolve_runs([str(days)]))
    start = decide_run_start(runs)
    assert start.mode == "separate" and start.temperatures_from_start and start.rest_h == SEPARATE_REST_H
    assert all(j >= CONTINUED_BELOW for j in start.jumps) and start.reason.startswith("4 of 4")
    cut = segments(runs[0], 4)
    jumps = start_jumps(cut)
    assert len(jumps) == 3 and max(jumps) < CONTINUED_BELOW
    cont = decide_run_start(cut)
    assert cont.mode == "continued" and not cont.temperatures_from_start and cont.rest_h == 0.0
    assert "continued" in cont.describe() and "carried" in cont.describe()


def test_the_user_can_force_the_mode_and_the_rest_and_a_bad_one_is_named(days):
    runs = load_runs(resolve_runs([str(days)]))
    forced = decide_run_start(runs, "continued", rest_h=1.5)
    assert (forced.mode, forced.temperatures_from_start, forced.rest_h, forced.reason) == \
        ("continued", False, 1.5, "as asked")
    assert decide_run_start(runs[:1]).mode == "continued"            # one run: nothing to lay end to end
    with pytest.raises(DatasetError, match="'sometimes'"):
        decide_run_start(runs, "sometimes")
    with pytest.raises(DatasetError, match="rest hours"):
        decide_run_start(runs, rest_h=-2.0)


def test_by_default_separate_days_are_scored_from_their_own_start(days):
    """Each day starts at another hall temperature and at displacement 0: the default (decided
    separate) fits the temperature changes and predicts a held-out day to its noise; forcing
    continued (absolute temperatures) leaves the per-day offset."""
    runs = load_runs(resolve_runs([str(days)]))
    fold = RunFold("f", (0, 1, 2), (), (3, 4))
    quiet = lambda s: None   # noqa: E731
    auto = evaluate_runs(runs, [fold], models=[STATIC], adaptive=False, progress=quiet)
    absolute = evaluate_runs(runs, [fold], models=[STATIC], adaptive=False, run_start="continued", progress=quiet)
    assert auto["run_start"]["mode"] == "separate" and auto["temperatures_from_start"] and auto["rest_h"] == 3.0
    assert auto["pooled"]["test"]["open_loop"]["static_ls"]["z_um"]["mae_um"] < 0.1
    assert absolute["pooled"]["test"]["open_loop"]["static_ls"]["z_um"]["mae_um"] > 1.0


def test_evaluate_says_how_the_runs_start_and_writes_it(days, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main([str(days), "--out", str(out), "--models", "static_ls", "--open-loop-only", "--no-progress",
               "--no-rerun", "--runs-split", "test=day4;validation=day3"])
    assert rc == 0
    f = json.loads((out / "evaluation_runs.json").read_text())
    assert f["run_start"]["mode"] == "separate" and len(f["run_start"]["jumps"]) == 4
    assert "runs start: separate" in capsys.readouterr().out
    rc = main([str(days), "--out", str(tmp_path / "o2"), "--models", "static_ls", "--open-loop-only",
               "--no-progress", "--no-rerun", "--runs-split", "test=day4;validation=day3", "--run-start",
               "continued"])
    assert rc == 0
    assert json.loads((tmp_path / "o2" / "evaluation_runs.json").read_text())["run_start"]["reason"] == "as asked"
