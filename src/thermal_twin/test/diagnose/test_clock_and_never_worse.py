"""Nuisances before the search and the rules after it, on the mini_mill twin.

- A common clock offset of the measured channels is estimated and removed, and the answer is
  ``none`` (it was ``unnamed`` with rate terms); a lag of one sensor is not taken for one.
- A channel is "worse" only when its held-out RMSE rises measurably and significantly beyond
  chance alignment with the twin's own residual there (a slow misfit the twin already has
  cannot refuse a change by itself; sensor noise can); an effect on one channel is judged on
  that channel.
- Adopted effects are refitted together and an extra that does not pay for itself on
  held-out data is dropped.
"""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from thermal_comp_common.recording_csv import Recording, column_kind
from thermal_eval.diagnose.concealed import HiddenEffect as H, concealed_recording, find_candidate, operating_programme
from thermal_twin.diagnose import clock
from thermal_twin.diagnose.diagnosis import diagnose, shared_channels
from thermal_twin.diagnose.fit import (FitProblem, acted_improvement_pct, chance_alignment_sd, fit_candidate,
                                      worse_channels)
from thermal_twin.diagnose.search_round import prune
from thermal_twin.machine.schema import load_machine

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()


def _shifted(rec: Recording, shift_s: float) -> Recording:
    """measured(t) = true(t + shift_s), as a recorder on another clock writes it."""
    t = rec.time_s
    cols = {k: (np.interp(t + shift_s, t, v) if column_kind(k) in ("sensor", "error") else v)
            for k, v in rec.columns.items()}
    return Recording(t, cols, source="shifted")


def _problem(rec: Recording) -> tuple[FitProblem, np.ndarray]:
    m = load_machine(SPEC)
    p = FitProblem(rec, shared_channels(m, rec), int(round(len(rec) * 2 / 3)))
    return p, p.outputs(SPEC)


def test_a_common_clock_offset_is_estimated_and_removed_before_the_search():
    rec, _ = concealed_recording(SPEC, (), hours=48.0, step_s=300.0, seed=2)
    shifted = _shifted(rec, 450.0)
    p, y = _problem(shifted)
    est = clock.estimate(shifted.time_s, p._meas, p._valid, y, p.n_train)
    assert est.applied and abs(est.shift_s - 450.0) < 75.0, est
    rep = diagnose(SPEC, shifted).report
    assert rep["clock_offset"]["applied"] and rep["answer"] == "none", (rep["answer"], rep["unnamed"])
    # without the step the same recording is not answered none: the offset is what it removes
    bare = diagnose(SPEC, shifted, clock_offset=False).report
    assert bare["answer"] != "none" or bare["unnamed"], bare["answer"]


def test_a_lag_of_one_sensor_is_not_taken_for_a_clock_offset():
    rec, _ = concealed_recording(SPEC, [H("time_lag", "table", None, (1800.0,))], hours=48.0, step_s=300.0,
                                 seed=1)
    p, y = _problem(rec)
    est = clock.estimate(rec.time_s, p._meas, p._valid, y, p.n_train)
    assert not est.applied and est.shift_s == 0.0, est


def test_worse_means_measurably_and_significantly_worse():
    rng = np.random.default_rng(0)
    t = np.arange(600) * 300.0
    truth = 20.0 + np.sin(t / 20000.0)
    cols = {"spindle_c": truth + 0.02 * rng.standard_normal(t.size),
            "head_c": truth + 0.02 * rng.standard_normal(t.size)}
    p = FitProblem(Recording(t, cols), ["spindle_c", "head_c"], 400)
    y0 = np.stack([truth, truth])
    slightly = y0 + np.array([[0.002], [0.0]])          # a tenth of the noise: not measurable
    stepped = y0 + np.array([[0.0], [0.03]])           # 1.5 noise sigmas on head_c
    assert worse_channels(p, y0, slightly) == []
    assert worse_channels(p, y0, stepped) == ["head_c"]
    assert worse_channels(p, stepped, y0) == []          # better is never worse


def test_chance_alignment_of_a_change_with_white_noise_is_the_noise_times_the_change():
    rng = np.random.default_rng(3)
    d = np.linspace(0.0, 2.0, 2000)
    # its square is unbiased for sigma^2 |d|^2 (white noise of sigma 0.5)
    var = [chance_alignment_sd(d, 0.5 * rng.standard_normal(d.size)) ** 2 for _ in range(40)]
    assert np.mean(var) == pytest.approx(0.25 * float(d @ d), rel=0.2)


def test_a_slow_misfit_the_twin_already_has_cannot_make_a_change_worse_but_noise_can():
    # the same change (a slow rise of 0.3 K over the held-out window) on two channels: on one the
    # twin already misfits by a slow 0.4 K swing that the change happens to meet against it, on
    # the other the twin is right up to white noise of 0.02 K; only the second is worse
    rng = np.random.default_rng(1)
    t = np.arange(900) * 300.0
    truth = 20.0 + np.sin(t / 30000.0)
    misfit = -0.4 * np.sin(np.pi * t / t[-1])
    cols = {"spindle_c": truth + misfit + 0.02 * rng.standard_normal(t.size),
            "head_c": truth + 0.02 * rng.standard_normal(t.size)}
    p = FitProblem(Recording(t, cols), ["spindle_c", "head_c"], 600)
    y0 = np.stack([truth, truth])
    change = np.where(t >= t[600], 0.3 * (t - t[600]) / (t[-1] - t[600]), 0.0)
    y1 = y0 + change
    r0 = cols["spindle_c"][600:] - y0[0, 600:]
    r1 = cols["spindle_c"][600:] - y1[0, 600:]
    assert np.sqrt(np.mean(r1 ** 2)) > 1.1 * np.sqrt(np.mean(r0 ** 2))        # measurably up on both
    assert worse_channels(p, y0, y1) == ["head_c"]


def test_an_extra_adoption_that_does_not_pay_for_itself_is_dropped():
    hidden = [H("heat_source", "table", "spindle_rpm", (40.0, 1.0))]
    rec, _ = concealed_recording(SPEC, hidden, hours=48.0, step_s=300.0, seed=1)
    p, y0 = _problem(rec)
    tl = operating_programme(SPEC, 48.0, 300.0, 1)
    true_c = find_candidate(SPEC, tl, "heat_source:table:spindle_rpm")
    h1 = fit_candidate(p, SPEC, true_c, y0)
    extra_c = find_candidate(SPEC, tl, "sensor_bias:column:-")
    h2 = fit_candidate(p, h1.spec, extra_c, p.outputs(h1.spec))
    kept, dropped = prune(p, SPEC, y0, [h1, h2], 5.0)
    assert [h.candidate.key for h in kept] == ["heat_source:table:spindle_rpm"], dropped
    assert dropped[0]["effect"] == "sensor_bias:column:-" and dropped[0]["holdout_gain_pct"] < 5.0
    assert abs(kept[0].values[0] - 40.0) < 6.0


def test_an_effect_on_one_channel_is_judged_on_that_channel():
    rng = np.random.default_rng(1)
    r0 = rng.standard_normal((20, 300))
    r0[3] += 3.0                                          # a bias of three sigmas on one channel of twenty
    r1 = r0.copy()
    r1[3] -= 3.0
    total = 100.0 * (1.0 - np.sum(r1 ** 2) / np.sum(r0 ** 2))
    assert total < 50.0 < acted_improvement_pct(r0, r1)   # diluted by nineteen untouched channels, not on its own
    assert acted_improvement_pct(r0, r0) == 0.0
