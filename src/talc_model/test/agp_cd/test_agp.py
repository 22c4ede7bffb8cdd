"""Adaptive Gaussian process: GP uncertainty, calibration length, recalibration, protocol."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agp_cd_synthetic import lathe_recording
from talc_model.adaptive_model import AdaptiveModel, make_model, model_from_state
from talc_model.agp.model import AdaptiveGaussianProcess, AgpConfigError, StaticGaussianProcess
from talc_model.agp.gaussian_process import ArdGaussianProcess
from talc_model.agp.offset_model import OffsetModel
from talc_model.open_loop.sensor_selection import SensorSelectionError, calibration_points_needed, sensor_groups
from thermal_eval.replay.virtual_experiment import run_virtual_experiment


def test_gp_uncertainty_rises_off_the_training_data():
    rng = np.random.default_rng(1)
    x = rng.uniform(0.0, 5.0, (120, 2))
    y = 3.0 * np.sin(x[:, 0]) + 0.5 * x[:, 1] + rng.normal(0, 0.05, 120)
    gp = ArdGaussianProcess().fit(x, y)
    inside_m, inside_s = gp.predict(np.array([[2.5, 2.5], [1.0, 4.0]]))
    far_m, far_s = gp.predict(np.array([[12.0, 2.5], [2.5, 20.0], [30.0, 30.0]]))
    truth_inside = 3.0 * np.sin([2.5, 1.0]) + 0.5 * np.array([2.5, 4.0])
    assert np.max(np.abs(inside_m - truth_inside)) < 0.2
    assert np.max(inside_s) < 0.3
    assert np.min(far_s) > 3 * np.max(inside_s)
    # the std grows monotonically as we walk away from the data along x0
    walk = np.column_stack([np.linspace(5.0, 15.0, 11), np.full(11, 2.5)])
    s = gp.predict(walk)[1]
    assert np.all(np.diff(s) > -1e-6) and s[-1] > 5 * s[0]
    # the noise std is learned near the true 0.05 and is part of the predictive std
    assert 0.01 < gp.noise_std < 0.2
    assert np.min(inside_s) >= gp.noise_std * 0.99


def test_gp_state_round_trip_predicts_identically():
    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 1, (60, 3))
    y = x[:, 0] ** 2 - x[:, 2] + rng.normal(0, 0.01, 60)
    gp = ArdGaussianProcess().fit(x, y)
    back = ArdGaussianProcess.from_state(json.loads(json.dumps(gp.to_state())))
    xt = rng.uniform(-2, 2, (20, 3))
    for a, b in zip(gp.predict(xt), back.predict(xt)):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-10)
    # ARD: the irrelevant input x1 gets the longest length scale
    assert np.argmax(gp.length_scales) == 1


def _grouped_sensors(n_groups: int, per_group: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 10, 300)
    # distinct frequencies over whole periods: the group signals are mutually uncorrelated
    latent = [np.sin(2 * np.pi * (g + 1) * t / 10.0 + g) for g in range(n_groups)]
    cols = []
    for g in range(n_groups):
        for _ in range(per_group):
            cols.append(rng.uniform(0.5, 3.0) * latent[g] + rng.uniform(-5, 5) + rng.normal(0, 0.02, t.size))
    return np.column_stack(cols)


@pytest.mark.parametrize("n_groups", [1, 2, 3, 4])
def test_kmeans_groups_of_correlated_sensors_set_the_calibration_length(n_groups):
    series = _grouped_sensors(n_groups, per_group=3, seed=n_groups)
    groups = sensor_groups(series)
    assert groups.n_groups == n_groups
    # sensors of one true group share a label
    labels = np.asarray(groups.labels).reshape(n_groups, 3)
    assert all(len(set(row)) == 1 for row in labels)
    n_min, _ = calibration_points_needed(series, points_per_group=10)
    assert n_min == 10 * n_groups


def test_sensor_groups_rejects_bad_shapes():
    with pytest.raises(SensorSelectionError, match="sensor series"):
        sensor_groups(np.zeros(10))
    with pytest.raises(SensorSelectionError, match=">= 3 complete rows"):
        sensor_groups(np.full((5, 2), np.nan))


def _feed(model, rec, k):
    temps = {c[:-2]: float(rec.columns[c][k]) for c in rec.names("sensor")}
    model.update_inputs(float(rec.time_s[k]), temps, {"spindle_rpm": float(rec.columns["spindle_rpm"][k])})


def _short_config(**extra):
    cfg = {"components": ["GB_X"], "calibration_probe_interval_s": 240.0, "min_calibration_s": 3 * 3600.0,
           "min_probe_interval_s": 240.0, "sigma_max_um": 2.0}
    cfg.update(extra)
    return cfg


def test_recalibration_is_triggered_when_the_std_exceeds_sigma_max():
    rec = lathe_recording(hours=14.0, dt=120.0, seed=3, oil_step_h=8.0, oil_step_c=10.0)
    model = AdaptiveGaussianProcess(_short_config(sigma_max_um=1.0))
    res = run_virtual_experiment(rec, model, probed_components=["GB_X"])
    assert model.phase == "compensation"
    assert res.recalibration_times_s, "the oil step must push the std over sigma_max"
    # every recalibration follows a step whose std exceeded the effective threshold
    for tr in res.recalibration_times_s:
        k = int(np.searchsorted(res.time_s, tr))
        assert res.std["GB_X"][k] > model.config.sigma_max
    # none before the oil step: the calibration covered the spindle-speed states
    assert min(res.recalibration_times_s) >= 8.0 * 3600.0
    # the static GP sees the same data, never recalibrates and does worse after the step
    static = StaticGaussianProcess(_short_config(sigma_max_um=1.0))
    res_s = run_virtual_experiment(rec, static, probed_components=["GB_X"])
    assert res_s.recalibration_times_s == []
    assert res.metrics["GB_X"]["rms_reduction_pct"] > res_s.metrics["GB_X"]["rms_reduction_pct"] + 10
    assert res.metrics["GB_X"]["rms_reduction_pct"] > 80


def test_no_probing_in_prediction_phase_while_std_is_below_sigma_max():
    rec = lathe_recording(hours=10.0, dt=120.0, seed=4, oil_step_h=None)
    model = AdaptiveGaussianProcess(_short_config(sigma_max_um=1e6))
    res = run_virtual_experiment(rec, model, probed_components=["GB_X"])
    t_cal_end = 3 * 3600.0 + 240.0
    assert model.phase == "compensation"
    assert all(t <= t_cal_end for t in res.probe_times_s)
    assert model.status(float(rec.time_s[-1])).next_probing_due_s == math.inf


def test_control_measurement_refits_only_beyond_the_tolerance():
    rec = lathe_recording(hours=8.0, dt=120.0, seed=5, oil_step_h=None)
    model = AdaptiveGaussianProcess(_short_config(sigma_max_um=1e6, control_interval_s=3600.0,
                                                  control_tolerance_um=1e6))
    run_virtual_experiment(rec, model, probed_components=["GB_X"])
    assert model.control_measurements >= 4 and model.recalibration_times == []
    model2 = AdaptiveGaussianProcess(_short_config(sigma_max_um=1e6, control_interval_s=3600.0,
                                                   control_tolerance_um=0.0))
    run_virtual_experiment(rec, model2, probed_components=["GB_X"])
    assert len(model2.recalibration_times) == model2.control_measurements >= 4


def test_agp_protocol_conformance_and_state_round_trip():
    rec = lathe_recording(hours=6.0, dt=120.0, seed=6, oil_step_h=4.5)
    model = make_model("agp", _short_config(sigma_max_um=1.0))
    assert isinstance(model, AdaptiveModel) and model.kind == "agp"
    assert model.component_names == ["GB_X"]
    k = 0
    # before any measurement: zero compensation, unknown std, a probe is due at once
    _feed(model, rec, 0)
    v, s = model.predict(float(rec.time_s[0]))
    assert v == {"GB_X": 0.0} and math.isnan(s["GB_X"])
    assert model.probe_due(float(rec.time_s[0]))
    model.add_failed_measurement(float(rec.time_s[0]), "probe skipped")
    probed_truth = []
    assert model.status(float(rec.time_s[0])).failed_probing_cycles == 1
    for k in range(1, len(rec)):
        _feed(model, rec, k)
        t = float(rec.time_s[k])
        v, _ = model.predict(t)
        if model.probe_due(t):
            true = float(rec.columns["GB_X_um"][k])
            probed_truth.append(true)
            model.add_measurement(t, {"GB_X": true - v["GB_X"]}, {"GB_X": v["GB_X"]})
        if model.phase == "compensation" and t > 4.0 * 3600.0:
            break
    st = model.status(float(rec.time_s[k]))
    assert st.phase == "compensation" and st.training_samples == st.probing_cycles > 0
    assert 0 < st.q_prod_pct < 100 and st.parameter_updates >= 1
    # the total error was rebuilt from residual + applied compensation: the training targets
    # are the true errors at the probing instants
    np.testing.assert_allclose(model.train_y["GB_X"], probed_truth, atol=1e-9)
    state = json.loads(json.dumps(model.to_state()))
    back = model_from_state(state)
    assert isinstance(back, AdaptiveGaussianProcess)
    for j in range(k + 1, min(k + 40, len(rec))):
        for m in (model, back):
            _feed(m, rec, j)
        t = float(rec.time_s[j])
        (va, sa), (vb, sb) = model.predict(t), back.predict(t)
        assert va["GB_X"] == pytest.approx(vb["GB_X"], rel=1e-9, abs=1e-9)
        assert sa["GB_X"] == pytest.approx(sb["GB_X"], rel=1e-9, abs=1e-9)
        assert model.probe_due(t) == back.probe_due(t)
    assert back.status(t).as_dict() == model.status(t).as_dict()


def test_nan_sensor_is_held_and_reported():
    model = AdaptiveGaussianProcess({"components": ["GB_X"]})
    model.update_inputs(0.0, {"a": 20.0, "b": 21.0}, {})
    model.update_inputs(60.0, {"a": float("nan"), "b": 21.5}, {})
    assert model.status(60.0).excluded_sensor_ids == ["a"]
    assert model.current_x.tolist() == [20.0, 21.5]


def test_bad_config_names_the_key():
    with pytest.raises(AgpConfigError, match="unknown key"):
        AdaptiveGaussianProcess({"sigma_maxx": 1.0})
    with pytest.raises(AgpConfigError, match="sigma_max_ratio"):
        AdaptiveGaussianProcess({"sigma_max_ratio": -0.1})
    with pytest.raises(AgpConfigError, match="kind"):
        AdaptiveGaussianProcess.from_state({"kind": "talc"})
    with pytest.raises(AgpConfigError, match="no inputs yet"):
        AdaptiveGaussianProcess({}).add_measurement(0.0, {"GB_X": 1.0}, {"GB_X": 0.0})


def test_multi_tcp_offset_model_extends_the_tls_prediction():
    train = lathe_recording(hours=20.0, dt=120.0, seed=7, oil_step_h=None)
    temps = {c[:-2]: train.columns[c] for c in train.names("sensor")}
    om = OffsetModel("T02_X", "GB_X", ["tool", "holder"]).fit(temps, train.columns["T02_X_um"],
                                                               train.columns["GB_X_um"], max_points=300)
    test = lathe_recording(hours=12.0, dt=120.0, seed=8, oil_step_h=None)
    cfg = _short_config(sigma_max_um=1.5, offset_models=[om.to_state()])
    model = make_model("agp", cfg)
    assert model.component_names == ["GB_X", "T02_X"]
    res = run_virtual_experiment(test, model, probed_components=["GB_X"])
    assert res.metrics["T02_X"]["rms_reduction_pct"] > 80
    # the tool component is the TLS prediction plus the predicted offset, never measured itself
    assert model.train_y.keys() == {"GB_X"}
    with pytest.raises(AgpConfigError, match="base"):
        make_model("agp", {"components": ["GB_X"], "offset_models": [{**om.to_state(), "base": "XX"}]})


def test_training_history_is_thinned_evenly_past_the_cap():
    model = AdaptiveGaussianProcess({"components": ["GB_X"], "max_training_points": 10})
    model.train_x = [[float(i)] for i in range(7)]
    assert model.training_rows().tolist() == list(range(7))
    model.train_x = [[float(i)] for i in range(95)]
    rows = model.training_rows()
    assert len(rows) == 10 and rows[0] == 0 and rows[-1] == 94
    assert np.all(np.diff(rows) >= 10) and np.all(np.diff(rows) <= 11)
    with pytest.raises(AgpConfigError, match="max_training_points"):
        AdaptiveGaussianProcess({"max_training_points": 3})


def test_hyperparameters_from_a_thinned_subset_keep_the_posterior_on_all_points():
    rng = np.random.default_rng(9)
    x = rng.uniform(0.0, 5.0, (240, 2))
    y = 3.0 * np.sin(x[:, 0]) + 0.5 * x[:, 1] + rng.normal(0, 0.05, 240)
    full = ArdGaussianProcess().fit(x, y)
    thin = ArdGaussianProcess(max_optimize_points=80).fit(x, y)
    assert thin.gpr.X_train_.shape[0] == 240                  # the posterior uses every point
    xt = rng.uniform(0.5, 4.5, (50, 2))
    truth = 3.0 * np.sin(xt[:, 0]) + 0.5 * xt[:, 1]
    assert np.max(np.abs(thin.predict(xt)[0] - truth)) < 0.2
    assert np.max(np.abs(thin.predict(xt)[0] - full.predict(xt)[0])) < 0.1
    assert thin.log_marginal_likelihood <= full.log_marginal_likelihood + 1e-6
