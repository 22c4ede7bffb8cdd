"""evaluate --probe-phases: the adaptive mode scored at several phases of the probing clock."""
from __future__ import annotations

import json

import numpy as np
import pytest

from synthetic_recording import synthetic, write_csv
from thermal_eval.evaluate.adaptive import AdaptiveSettingsError, ProbingBudget, phase_budgets, probe_schedule
from thermal_eval.bench.evaluate import _adaptive_targets
from thermal_eval.evaluate.cli import main
from thermal_eval.evaluate.run import PHASE_KEYS, available_models, evaluate
from thermal_eval.evaluate.spec import evaluation_data
from thermal_comp_common.recording_csv import Recording


def _data():
    cols = synthetic()
    return evaluation_data(Recording(cols.pop("time_s"), cols), {})


def test_the_phases_delay_the_probing_clock_by_fractions_of_the_interval():
    d = _data()
    quiet = {"z_um": np.zeros(len(d))}               # never asks: the schedule and the cap alone
    budget = ProbingBudget(probe_every_h=1.0, max_probes_per_h=1.0)
    budgets = phase_budgets(budget, 4)
    assert budgets[0] is budget and [b.phase_h for b in budgets] == [0.0, 0.25, 0.5, 0.75]
    rows0, _ = probe_schedule(d, quiet, budget)
    assert len(rows0) >= 3
    for i, b in enumerate(budgets[1:], start=1):
        rows, _ = probe_schedule(d, quiet, b)
        shift = 15 * i                               # 60-s rows: a quarter hour is 15 rows
        assert rows == [r + shift for r in rows0 if r + shift < len(d)]
        assert d.time_s[rows[0]] - d.time_s[d.split.n_train - 1] >= 3600.0 * (1.0 + b.phase_h)
    with pytest.raises(AdaptiveSettingsError, match="probe_phases: 0"):
        phase_budgets(budget, 0)
    with pytest.raises(AdaptiveSettingsError, match="phase_h"):
        ProbingBudget(phase_h=-0.1)


def test_k_phases_keep_phase_0_figures_and_give_mean_and_worst_over_the_phases():
    d = _data()
    models = available_models(d, ["lagged_ridge"])
    one = evaluate(d, models=models, show_progress=False)
    three = evaluate(d, models=models, show_progress=False, probe_phases=3)
    a1, a3 = one.figures["adaptive"]["lagged_ridge"], three.figures["adaptive"]["lagged_ridge"]
    assert "probe_phases" not in a1 and a3["probe_phases"]["k"] == 3
    assert a3["probe_phases"]["offsets_h"] == [0.0, pytest.approx(1 / 3, abs=1e-4), pytest.approx(2 / 3, abs=1e-4)]
    assert a3["probe_phases"]["probings_after_calibration"][0] == a1["probings_after_calibration"]
    for ch in d.channels:
        c1, c3 = a1["channels"][ch], dict(a3["channels"][ch])
        ph = c3.pop("phases")
        assert c3 == c1                                  # phase 0 is today's run, exactly
        by = ph["by_phase"]
        assert [by[k][0] for k in PHASE_KEYS] == [c1[k] for k in PHASE_KEYS]
        assert len(set(by["mae_test_um"])) > 1 or len(set(by["hold_own_probes_mae_test_um"])) > 1   # really shifted
        for k in PHASE_KEYS:
            assert ph["mean"][k] == pytest.approx(np.mean(by[k]), abs=1e-3)
        assert ph["worst"]["mae_test_um"] == max(by["mae_test_um"])
        assert ph["mean"]["ratio_to_hold_test"] == pytest.approx(
            ph["mean"]["mae_test_um"] / ph["mean"]["hold_own_probes_mae_test_um"], abs=1e-3)
    assert np.array_equal(one.adaptive["lagged_ridge"]["z_um"], three.adaptive["lagged_ridge"]["z_um"], equal_nan=True)
    # holding beside each phase holds that phase's own probes, at its own instants
    from thermal_comp_common.metrics import mae
    from thermal_eval.evaluate.model_rows import hold_probes
    start = d.split.n_train
    for i, b in enumerate(phase_budgets(ProbingBudget(), 3)):
        rows, _ = probe_schedule(d, three.open_loop["lagged_ridge"], b)
        assert len(rows) == a3["probe_phases"]["probings_after_calibration"][i]
        for ch in d.channels:
            y = d.displacement_um[ch]
            h = hold_probes(y, [start - 1] + rows, len(d))
            assert a3["channels"][ch]["phases"]["by_phase"]["hold_own_probes_mae_test_um"][i] == round(
                mae(y[d.split.test], h[d.split.test]), 3)
    targets = _adaptive_targets(three.figures)["lagged_ridge"]
    assert targets["worst_channel_mae_um"] == _adaptive_targets(one.figures)["lagged_ridge"]["worst_channel_mae_um"]
    worst_mean = max(max(a3["channels"][ch]["phases"]["mean"]["mae_test_um"],
                         a3["channels"][ch]["phases"]["mean"]["mae_validation_um"]) for ch in d.channels)
    assert targets["phase_mean"]["worst_channel_mae_um"] == pytest.approx(worst_mean, abs=1e-3)
    assert targets["phase_mean"]["phases"] == 3


def test_cli_prints_the_phase_rows_and_refuses_a_bad_k(tmp_path, capsys):
    p = tmp_path / "rec.csv"
    write_csv(p, synthetic())
    out = tmp_path / "out"
    assert main([str(p), "--out", str(out), "--models", "lagged_ridge", "--no-progress", "--no-rerun",
                 "--probe-phases", "2"]) == 0
    f = json.loads((out / "evaluation.json").read_text())
    assert f["probe_phases"] == 2 and "phases" in f["adaptive"]["lagged_ridge"]["channels"]["z_um"]
    text = capsys.readouterr().out
    assert "mean of 2 phases" in text and "worst phase" in text
    assert main([str(p), "--out", str(tmp_path / "o2"), "--probe-phases", "0", "--no-progress"]) == 2
    assert "probe_phases: 0" in capsys.readouterr().err


def test_the_forgetting_row_is_opt_in_and_chooses_its_factor_on_the_training_rows():
    from thermal_eval.evaluate.run import WALK_FORWARD_PHASES
    from talc_model.open_loop.probe_gain_update import FORGETTINGS
    d = _data()
    assert "arx_subgrid_gain_forgetting" not in [m.name for m in available_models(d)]
    res = evaluate(d, models=available_models(d, ["arx_subgrid_gain_forgetting"]), show_progress=False)
    held = dict(d.displacement_um)
    for ch in d.channels:
        info = res.figures["open_loop"]["arx_subgrid_gain_forgetting"]["channels"][ch]["probe_gain_update"]
        assert info["forgetting"] in FORGETTINGS and info["walk_forward_phases"] == WALK_FORWARD_PHASES
        assert len(info["walk_forward_mae_um"]) == 4 * len(FORGETTINGS)
        assert "mae_test_um" in res.figures["adaptive"]["arx_subgrid_gain_forgetting"]["channels"][ch]
    for ch in d.channels:    # the choice reads no held-out row
        d.displacement_um[ch] = np.where(np.arange(len(d)) < d.split.n_train, held[ch], 1e6)
    again = evaluate(d, models=available_models(d, ["arx_subgrid_gain_forgetting"]), adaptive=True, show_progress=False)
    for ch in d.channels:
        a = res.figures["open_loop"]["arx_subgrid_gain_forgetting"]["channels"][ch]["probe_gain_update"]
        b = again.figures["open_loop"]["arx_subgrid_gain_forgetting"]["channels"][ch]["probe_gain_update"]
        assert a == b
