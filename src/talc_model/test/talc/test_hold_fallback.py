"""talc_model.probing.hold_fallback: the prequential switch between a model and its last probe, the
resolution of a quantised signal, and the fall-back inside TALC, the AGP and the CD model."""
import json
import math

import numpy as np
import pytest

from talc_model.adaptive_model import make_model
from talc_model.probing.hold_fallback import (MIN_SCORED, MODE_HOLD, MODE_MODEL, HoldFallback, noise_bound,
                                              probe_totals, resolution, window_scores)


def test_resolution_of_a_quantised_signal_and_none_of_a_continuous_one():
    rng = np.random.default_rng(0)
    steps = 0.13 * rng.integers(-3, 4, 60)
    assert resolution(steps) == pytest.approx(0.13)
    assert math.isnan(resolution(rng.normal(0, 0.2, 60)))
    assert math.isnan(resolution([0.13, 0.26]))                # too few steps to tell


def test_probe_totals_add_the_applied_compensation_and_skip_unprobed():
    assert probe_totals({"a": 1.0, "b": math.nan}, {"a": 2.0, "b": 5.0}) == {"a": 3.0}
    assert probe_totals({"a": 1.0}, {"a": math.nan}) == {"a": 1.0}


def _drive_core(hf, truth, model_error, probe_every=10):
    """Probe every ``probe_every`` steps; the model predicts truth + model_error(k)."""
    out = []
    for k, y in enumerate(truth):
        v = hf.output(float(k), {"c": y + model_error(k)}, True)["c"]
        out.append(v)
        if k % probe_every == 0:
            hf.observe(float(k), {"c": y})
    return np.array(out)


def test_a_model_worse_than_holding_is_held_and_a_good_one_earns_the_model_mode():
    t = np.arange(400)
    truth = 0.01 * t                                   # a steady drift: holding lags it
    rng = np.random.default_rng(1)
    bad = HoldFallback(["c"], trusted=True)
    _drive_core(bad, truth, lambda k: rng.normal(0, 3.0))
    assert bad.mode("c") == MODE_HOLD and bad.components["c"].switches == 1
    good = HoldFallback(["c"])
    assert good.mode("c") == MODE_HOLD                 # from zero: the model earns its mode
    _drive_core(good, truth, lambda k: 0.0)
    assert good.mode("c") == MODE_MODEL
    assert good.diagnostics()["c"]["ratio_to_hold"] < 0.2    # its start error is read one step after a probe


def test_no_switch_before_min_scored_and_hysteresis_between_the_thresholds():
    hf = HoldFallback(["c"], trusted=True, noise_std={"c": 0.0})
    for k in range(MIN_SCORED):                        # scored probes 1 .. MIN_SCORED-1 decide nothing
        hf.output(float(k), {"c": 10.0}, True)
        hf.observe(float(k), {"c": 0.0})
    assert hf.mode("c") == MODE_MODEL
    hf.output(float(MIN_SCORED), {"c": 10.0}, True)
    hf.observe(float(MIN_SCORED), {"c": 0.0})
    assert hf.mode("c") == MODE_HOLD
    comp = hf.components["c"]
    comp.scores.clear()
    comp.scores.extend([(0.85, 2.0, 60.0)] * 8)       # ratio 0.85 / (2.0 / 2): between 0.8 and 0.95
    hf._decide(comp)
    assert hf.mode("c") == MODE_HOLD


def test_hold_mode_outputs_the_last_probe_and_disabled_passes_the_model():
    hf = HoldFallback(["c"], horizon_s=3600.0)
    hf.observe(0.0, {"c": 2.5})
    assert hf.output(1.0, {"c": 9.0}, True) == {"c": 2.5}
    assert hf.output(1.0, {"c": 9.0}, False) == {"c": 2.5}     # calibration: no prediction yet, hold
    off = HoldFallback(["c"], enabled=False)
    off.observe(0.0, {"c": 2.5})
    assert off.output(1.0, {"c": 9.0}, True) == {"c": 9.0}


def _plateau(hours=48.0, step_s=300.0, seed=3):
    """A temperature-driven error quantised in 0.13-um steps with slow plateaus."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, step_s)
    amb = 20.0 + np.cumsum(rng.normal(0, 0.02, t.size)) + 0.8 * np.sin(2 * np.pi * t / 86400.0)
    smooth = np.convolve(amb - amb[0], np.ones(24) / 24, mode="full")[: t.size]
    return t, amb, 0.13 * np.round(0.6 * smooth / 0.13)


def _closed_loop(model, t, amb, y):
    out, probes = np.zeros_like(y), []
    for k in range(t.size):
        model.update_inputs(float(t[k]), {"amb": float(amb[k])}, {})
        v, _ = model.predict(float(t[k]))
        out[k] = v["E"]
        if model.probe_due(float(t[k])):
            model.add_measurement(float(t[k]), {"E": y[k] - v["E"]}, {"E": v["E"]})
            probes.append(k)
    hold = np.zeros_like(y)
    for a, b in zip(probes, probes[1:] + [t.size - 1]):
        hold[a + 1:b + 1] = y[a]
    return out, hold, probes


@pytest.mark.parametrize("kind,config", [
    ("talc", {"component_names": ["E"], "angular_components": [], "input_names": ["amb"], "post_cp_interval_h": 1.0}),
    ("agp", {"components": ["E"], "sensors": ["amb"], "control_interval_s": 3600.0, "min_calibration_s": 7200.0,
             "max_expected_error_um": 10.0}),
    ("cd", {"components": ["E"], "sensors": ["amb"], "min_calibration_s": 7200.0, "max_inputs": 1,
            "calibration_probe_interval_s": 900.0, "update_probe_interval_s": 3600.0}),
])
def test_on_a_quantised_plateau_signal_each_model_is_within_10_percent_of_holding_its_probes(kind, config):
    t, amb, y = _plateau()
    model = make_model(kind, config)
    out, hold, probes = _closed_loop(model, t, amb, y)
    rows = slice(probes[0] + 1, None)
    mae, mae_hold = np.mean(np.abs(y[rows] - out[rows])), np.mean(np.abs(y[rows] - hold[rows]))
    assert mae <= 1.1 * mae_hold + 1e-9, (kind, mae, mae_hold)
    status = model.status(float(t[-1]))
    assert "quantised in 0.13 steps" in status.message
    diag = model.hold.diagnostics()["E"]
    assert diag["resolution"] == pytest.approx(0.13)
    back = type(model).from_state(json.loads(json.dumps(model.to_state())))
    assert back.hold.diagnostics()["E"]["mode"] == diag["mode"]
    assert back.hold.components["E"].last_total == model.hold.components["E"].last_total


def test_short_intervals_are_scaled_to_the_models_probing_interval():
    """Probes 5 min apart (a prior's check phase) must not make holding look better than it is
    at the model's 2-h interval: holding's error is scaled to it, the model's is not."""
    scores = [(0.2, 0.1, 300.0)] * 8                # model 0.2 um off; holding 0.1 / 2 um after 5 min
    short, scaled = (HoldFallback(["c"], trusted=True, noise_std={"c": 0.0}),
                     HoldFallback(["c"], trusted=True, horizon_s=7200.0, noise_std={"c": 0.0}))
    for hf in (short, scaled):
        hf.components["c"].scores.extend(scores)
        hf._decide(hf.components["c"], hf.horizon_s)
    assert short.mode("c") == MODE_HOLD and scaled.mode("c") == MODE_MODEL
    with pytest.raises(ValueError, match="horizon_s"):
        HoldFallback(["c"], horizon_s=-1.0)


def _noisy_probes(hf, truth, model_error, noise, rng, every=120, rows=2400):
    """Probe every ``every`` minutes with Gaussian probe noise; the model predicts truth + model_error."""
    for k in range(rows):
        t = 60.0 * k
        hf.output(t, {"c": truth(t) + model_error}, True)
        if k % every == 0:
            hf.observe(t, {"c": truth(t) + rng.normal(0.0, noise)})


def test_probe_noise_does_not_make_holding_look_better_than_a_good_model():
    """A prior-started model as good as the truth on a signal that drifts little against the probe
    noise: the model's error at a probe is one noise draw, holding's step two; scored like with
    like the model keeps its mode (holding carries the held probe's noise all interval)."""
    rng = np.random.default_rng(5)
    hf = HoldFallback(["c"], trusted=True, horizon_s=7200.0, noise_std={"c": 0.25})
    _noisy_probes(hf, lambda t: 0.1 * math.sin(t / 40000.0), 0.0, 0.25, rng)
    assert hf.mode("c") == MODE_MODEL and hf.components["c"].switches == 0
    assert hf.diagnostics()["c"]["ratio_to_hold"] < 0.8
    naive = HoldFallback(["c"], trusted=True, horizon_s=7200.0, noise_std={"c": 0.0})   # noise not accounted
    _noisy_probes(naive, lambda t: 0.1 * math.sin(t / 40000.0), 0.0, 0.25, np.random.default_rng(5))
    assert naive.diagnostics()["c"]["ratio_to_hold"] > 1.0


def test_a_model_offset_by_three_noise_stds_is_held_on_a_flat_signal():
    rng = np.random.default_rng(6)
    hf = HoldFallback(["c"], trusted=True, horizon_s=7200.0, noise_std={"c": 0.25})
    _noisy_probes(hf, lambda t: 0.0, 0.75, 0.25, rng)
    assert hf.mode("c") == MODE_HOLD


def test_noise_bound_from_second_differences_and_none_on_a_quantised_signal():
    rng = np.random.default_rng(7)
    t = np.arange(40) * 3600.0
    drift = 2.0 * t / 3600.0                                    # 2 um per hour: a line cancels
    bound = noise_bound(zip(t, drift + rng.normal(0, 0.3, t.size)))
    assert 0.2 < bound < 0.45
    assert math.isnan(noise_bound(zip(t[:5], drift[:5])))      # too few probes to tell
    hf = HoldFallback(["c"], horizon_s=3600.0, noise_std={"c": 0.25})
    for k, v in enumerate(0.13 * np.round(np.cumsum(rng.normal(0, 0.1, 60)) / 0.13)):
        hf.observe(3600.0 * k, {"c": float(v)})
    assert hf.diagnostics()["c"]["noise_std"] == 0.0           # quantised: the held value is exact
    assert all(math.isnan(x) for x in window_scores([], 0.1))  # nothing scored


def test_a_probe_older_than_its_score_covers_is_not_held():
    hf = HoldFallback(["c"], horizon_s=3600.0, noise_std={"c": 0.0})
    hf.observe(0.0, {"c": 1.0})
    assert hf.output(3000.0, {"c": 5.0}, True) == {"c": 1.0}   # hold mode, within the horizon
    assert hf.output(4000.0, {"c": 5.0}, True) == {"c": 5.0}   # unscored beyond it: the model
    assert hf.diagnostics()["c"]["stale"] and "the model's output on c" in hf.note()
    assert hf.output(4000.0, {"c": 5.0}, False) == {"c": 1.0}  # no prediction: still the probe


def test_a_state_saved_with_half_steps_is_read_as_whole_steps():
    hf = HoldFallback(["c"], horizon_s=3600.0)
    state = hf.to_state()
    old = {**state["components"]["c"], "scores": [[0.2, 0.5, 3600.0]]}
    del old["score_form"], old["probes"]
    back = HoldFallback.from_state({"components": {"c": old}, "keeps_model": True}, ["c"], True, 3600.0)
    assert list(back.components["c"].scores) == [(0.2, 1.0, 3600.0)] and back.trusted
