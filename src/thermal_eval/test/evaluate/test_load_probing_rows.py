"""evaluate --load-probing: the load-change rule of talc_model.open_loop.load_probing in evaluate's
probing budget, chosen on the training rows by walk-forward."""
from __future__ import annotations

import numpy as np
import pytest

from synthetic_recording import synthetic
from talc_model.open_loop.load_probing import input_steps, within_bucket_bound
from thermal_comp_common.recording_csv import Recording
from thermal_eval.evaluate.adaptive import AdaptiveSettingsError, ProbingBudget, phase_budgets, probe_schedule
from thermal_eval.evaluate.load_probing_choice import choose_load_probing
from thermal_eval.evaluate.run import available_models, evaluate
from thermal_eval.evaluate.spec import evaluation_data


def _data(**spec):
    cols = synthetic()
    return evaluation_data(Recording(cols.pop("time_s"), cols), spec)


def test_the_recording_steps_every_two_hours_and_bad_budgets_name_the_setting():
    d = _data()
    assert input_steps(d.inputs, d.split.n_train).tolist() == list(range(120, 900, 120))
    with pytest.raises(AdaptiveSettingsError, match="bucket_credit"):
        ProbingBudget(bucket_credit=1.5)
    with pytest.raises(AdaptiveSettingsError, match="bucket_depth"):
        ProbingBudget(bucket_depth=0.0)
    with pytest.raises(AdaptiveSettingsError, match="load_delay_min"):
        ProbingBudget(load_delay_min=-1.0)


def test_a_step_makes_a_probing_due_d_minutes_later():
    d = _data()
    quiet = {"z_um": np.zeros(len(d))}               # never asks: the rule alone (the schedule is far)
    b = ProbingBudget(probe_every_h=100.0, load_delay_min=10.0, bucket_depth=2.0)
    rows, asked = probe_schedule(d, quiet, b)
    assert rows == [610, 730, 850] and asked == rows  # steps at 600, 720, 840 (60-s rows) + 10 min
    assert probe_schedule(d, quiet, ProbingBudget(probe_every_h=100.0))[0] == []     # off: nothing asks


def test_phases_shift_only_the_clock():
    d = _data()
    quiet = {"z_um": np.zeros(len(d))}
    b = ProbingBudget(probe_every_h=1.0, max_probes_per_h=2.0, load_delay_min=10.0, bucket_depth=3.0, min_gap_s=60.0)
    loads, regular = [], []
    for ph in phase_budgets(b, 3):
        rows, asked = probe_schedule(d, quiet, ph)
        clock0 = d.time_s[d.split.n_train - 1] + 3600.0 * ph.phase_h
        assert d.time_s[rows[0]] >= clock0 and within_bucket_bound(d.time_s, rows, clock0, 2.0)
        loads.append(asked)
        regular.append([r for r in rows if r not in asked])
    for asked in loads:              # at the machine's steps + 10 min (a cycle just before: + its 95 s + gap)
        assert [r - s for r, s in zip(asked, (600, 720, 840))] in ([10, 10, 10], [12, 10, 10])
    assert regular[0] != regular[1] != regular[2]                   # the clock's probings moved


def test_no_inputs_means_the_rule_is_off():
    d = _data(inputs=[])
    assert d.inputs is None
    models = available_models(d, ["lagged_ridge"])
    off = evaluate(d, models=models, show_progress=False)
    on = evaluate(d, models=models, show_progress=False, load_probing=True)
    a_off, a_on = off.figures["adaptive"]["lagged_ridge"], dict(on.figures["adaptive"]["lagged_ridge"])
    assert a_on.pop("load_probing") == {"chosen": "off", "why": "no machine inputs"}
    assert a_on == a_off and a_on["probings_after_input_steps"] == 0


def test_the_choice_is_made_on_the_training_rows_only():
    d = _data()
    models = available_models(d, ["lowpass_ridge_refit"])
    res = evaluate(d, models=models, show_progress=False, load_probing=True)
    row = res.figures["adaptive"]["lowpass_ridge_refit"]
    choice = row["load_probing"]
    assert choice["walk_forward_rows"] == [270, 540] and choice["steps_on_training_rows"] == 4
    assert choice["chosen"] == min(choice["walk_forward_mae_um"], key=choice["walk_forward_mae_um"].get)
    poisoned = evaluate(_poisoned(d), models=models, show_progress=False, load_probing=True)
    assert poisoned.figures["adaptive"]["lowpass_ridge_refit"]["load_probing"] == choice
    if choice["chosen"] != "off":
        assert row["probings_after_input_steps"] >= 1
    hours = (d.time_s[-1] - d.time_s[d.split.n_train - 1]) / 3600.0
    assert row["probings_after_calibration"] <= 1 + 1.0 * hours


def _poisoned(d):
    """The held-out displacements replaced by a huge ramp: a choice that read them would change."""
    from dataclasses import replace
    n = d.split.n_train
    disp = {c: np.r_[y[:n], 1e3 * np.arange(len(y) - n)] for c, y in d.displacement_um.items()}
    return replace(d, displacement_um=disp)


def test_choose_without_steps_on_the_training_rows_is_off():
    d = _data()
    flat = np.r_[np.full(d.split.n_train, 3000.0), np.full(len(d) - d.split.n_train, 900.0)]
    from dataclasses import replace
    d2 = replace(d, inputs=flat[:, None])
    budget, info = choose_load_probing(d2, 270, {}, ProbingBudget(), 6)
    assert budget.load_delay_min is None and info == {"chosen": "off",
                                                      "why": "no machine-input step on the training rows"}


def test_the_cli_takes_the_rule_and_a_zero_credit_keeps_the_average(tmp_path):
    import json

    from synthetic_recording import write_csv
    from thermal_eval.evaluate.cli import main
    write_csv(tmp_path / "r.csv", synthetic())
    assert main([str(tmp_path / "r.csv"), "--out", str(tmp_path / "o"), "--models", "lagged_ridge", "--load-probing",
                 "--bucket-credit", "0", "--probe-phases", "3", "--no-rerun", "--no-progress"]) == 0
    f = json.loads((tmp_path / "o" / "evaluation.json").read_text())
    assert f["load_probing"] is True and f["budget"]["bucket_credit"] == 0.0
    row = f["adaptive"]["lagged_ridge"]
    assert row["load_probing"]["chosen"] in row["load_probing"]["walk_forward_mae_um"]
    assert all(p <= 1.0 for p in row["probe_phases"]["probings_per_h_after_calibration"])
