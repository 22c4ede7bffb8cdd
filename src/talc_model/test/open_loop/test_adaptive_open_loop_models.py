"""The registered streaming forms of the probe gain update, the probe refit and the load-change
rule: built by kind, the same numbers as the batch functions ``evaluate`` uses, state round trips."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from talc_model import (AdaptiveModel, LoadBucketProbing, ProbeGainUpdateModel, ProbeRefitModel, make_model,
                        model_from_state)
from talc_model.open_loop.lagged_temperature_model import LaggedTemperatureModel, lagged_features
from talc_model.open_loop.load_probing import LoadProbingError, within_bucket_bound
from talc_model.open_loop.probe_gain_update import GainUpdateError, lagged_contributions, regained_compensation
from talc_model.open_loop.probe_refit import RefitError, RidgeRefit
from talc_model.open_loop.probed_lagged import LaggedFeatureStream

SENSORS = ["t_bed", "t_spindle"]
SMALL = {"component_names": ["E_X0C"], "taus_s": [3600.0], "alpha": 0.1, "calibration_probes": 24,
         "calibration_interval_s": 1800.0, "probe_every_s": 3600.0}


def _plant(n=1400, step_s=300.0, gain_after=2.0, seed=0):
    """Two temperatures and a displacement on them; after 12 h the machine's gain on the first
    sensor's 1-h low-pass moves from 1 to ``gain_after`` (the displacement stays continuous)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * step_s
    temps = np.column_stack([20 + 3 * np.sin(t / 20000.0) + 0.5 * np.sin(t / 4000.0),
                             22 + 2 * (1 - np.exp(-t / 50000.0)) + 0.3 * np.cos(t / 7000.0)])
    feats = lagged_features(t, temps, (3600.0,))
    lp = feats[:, 2]
    gain = np.where(t < 43200.0, 1.0, gain_after)
    y = 4.0 * lp + (gain - 1.0) * 4.0 * (lp - lp[int(43200.0 / step_s)]) - 1.5 * feats[:, 1]
    return t, temps, y + rng.normal(0, 0.005, n), {"spindle_rpm": np.where((t // 21600.0) % 2 == 0, 1000.0, 4000.0)}


def _run(model, t, temps, y, machine, start=0, stop=None):
    """Drive ``model`` over rows [start, stop): predictions, and the probe rows."""
    preds = np.full(len(t), np.nan)
    probes = []
    for k in range(start, len(t) if stop is None else stop):
        model.update_inputs(t[k], dict(zip(SENSORS, temps[k])), {key: v[k] for key, v in machine.items()})
        preds[k] = model.predict(t[k])[0]["E_X0C"]
        if model.probe_due(t[k]):
            model.add_measurement(t[k], {"E_X0C": y[k] - preds[k]}, {"E_X0C": preds[k]})
            probes.append(k)
    return preds, probes


@pytest.mark.parametrize("kind, cls", [("probe_gain_update", ProbeGainUpdateModel), ("probe_refit", ProbeRefitModel),
                                       ("load_bucket", LoadBucketProbing)])
def test_each_kind_is_built_by_make_model_and_names_a_bad_setting(kind, cls):
    model = make_model(kind, {})
    assert type(model) is cls and model.kind == kind and isinstance(model, AdaptiveModel)
    with pytest.raises(ValueError, match="no_such_key"):
        make_model(kind, {"no_such_key": 1})
    with pytest.raises(GainUpdateError, match="penalty"):
        make_model("probe_gain_update", {"penalty": 0.0})
    with pytest.raises(RefitError, match="weight"):
        make_model("probe_refit", {"weight": -0.1})
    with pytest.raises(LoadProbingError, match="depth"):
        make_model("load_bucket", {"depth": 0.5})


def test_the_feature_stream_is_the_batch_features_row_by_row():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(30.0, 400.0, 300))               # irregular samples
    temps = 20 + np.cumsum(rng.normal(0, 0.05, (300, 3)), axis=0)
    temps[40:45, 1] = np.nan                                    # a sensor drops out: its filters hold
    stream = LaggedFeatureStream([0.0, 900.0, 7200.0])
    rows = np.array([stream.update(tk, temps[k]) for k, tk in enumerate(t)])
    assert np.allclose(rows, lagged_features(t, temps, (0.0, 900.0, 7200.0)), rtol=0, atol=1e-9)
    assert np.abs(rows[:, 3:6]).max() > 0.1                     # not trivially zero


def _calibrated(model, t, temps, probes):
    """The batch ridge fitted on the streaming model's calibration probes, and the last of them."""
    feats = lagged_features(t, temps, (3600.0,))
    calib = probes[:SMALL["calibration_probes"]]
    ridge = model.ridges["E_X0C"]
    again = LaggedTemperatureModel((3600.0,), 0.1).fit(feats[calib], np.asarray(model.calibration_y["E_X0C"]))
    assert np.allclose(ridge.coef_, again.coef_, rtol=0, atol=1e-9)
    return feats, ridge, calib[-1]


def test_the_streaming_gain_update_is_the_batch_update_and_follows_a_drifted_gain():
    t, temps, y, machine = _plant()
    model = make_model("probe_gain_update", {**SMALL, "penalty": 1.0})
    preds, probes = _run(model, t, temps, y, machine)
    feats, ridge, last_calib = _calibrated(model, t, temps, probes)
    start = last_calib + 1
    measured = [last_calib] + [r for r in probes if r > last_calib]
    batch = regained_compensation(y, ridge.predict(feats), lagged_contributions(ridge, feats), measured, start,
                                  len(t), 1.0)
    after = [k for k in range(start, len(t)) if k not in measured]   # a probe row is predicted before its probe
    assert np.allclose(preds[after], batch[after], rtol=0, atol=1e-8)
    fixed = regained_compensation(y, ridge.predict(feats), lagged_contributions(ridge, feats), measured, start,
                                  len(t), 1e9)                          # gains held at calibration
    late = slice(len(t) // 2, len(t))
    assert np.mean(np.abs(y[late] - preds[late])) < 0.5 * np.mean(np.abs(y[late] - fixed[late]))
    st = model.status(t[-1])
    assert st.phase == "compensation" and st.training_samples == 24 and st.parameter_updates == len(measured) - 1


def test_the_streaming_refit_is_the_batch_refit():
    t, temps, y, machine = _plant()
    cfg = {**SMALL, "weight": 0.3, "own_level": True}
    model = make_model("probe_refit", cfg)
    preds, probes = _run(model, t, temps, y, machine)
    feats, ridge, last_calib = _calibrated(model, t, temps, probes)
    calib = probes[:SMALL["calibration_probes"]]
    z = (feats - ridge.mean_) / ridge.scale_
    ym = float(np.mean(y[calib]))
    batch_model = RidgeRefit(z, z[calib].T @ z[calib], z[calib].T @ (y[calib] - ym), len(calib), ym, 0.1, 0.3, True)
    measured = [last_calib] + [r for r in probes if r > last_calib]
    batch = batch_model.compensation(y, measured, last_calib + 1, len(t))
    after = [k for k in range(last_calib + 1, len(t)) if k not in measured]
    assert np.allclose(preds[after], batch[after], rtol=0, atol=1e-8)
    held = RidgeRefit(z, batch_model.gram, batch_model.zy, len(calib), ym, 0.1).compensation(
        y, measured, last_calib + 1, len(t))
    late = slice(len(t) // 2, len(t))
    assert np.mean(np.abs(y[late] - preds[late])) < 0.5 * np.mean(np.abs(y[late] - held[late]))


def test_the_bucket_probes_after_each_step_within_its_bound():
    t, temps, y, machine = _plant()
    cfg = {"model_kind": "probe_refit", "model_config": {**SMALL, "probe_every_s": 36000.0},
           "step_sizes": {"spindle_rpm": 500.0}, "delay_s": 600.0, "rate_per_h": 0.5, "depth": 3.0,
           "probe_every_s": 36000.0}
    model = make_model("load_bucket", cfg)
    _, probes = _run(model, t, temps, y, machine)
    calib_end = probes[SMALL["calibration_probes"] - 1]
    after = [r for r in probes if r > calib_end]
    steps = [k for k in range(1, len(t)) if machine["spindle_rpm"][k] != machine["spindle_rpm"][k - 1]]
    assert [r - s for r, s in zip(after, [s for s in steps if s > calib_end])] == [2] * len(after)   # 600 s later
    assert len(after) == model.load_probings == len([s for s in steps if s > calib_end]) >= 5
    assert within_bucket_bound(t, after, t[calib_end], 0.5)
    quiet = make_model("load_bucket", {**cfg, "step_sizes": {}})         # no step rule: the 10-h schedule only
    _, quiet_probes = _run(quiet, t, temps, y, machine)
    assert len([r for r in quiet_probes if r > calib_end]) == math.floor((t[-1] - t[calib_end]) / 36000.0)


@pytest.mark.parametrize("kind, cfg", [
    ("probe_gain_update", {**SMALL, "penalty": 1.0, "forgetting": 0.8}),
    ("probe_refit", {**SMALL, "weight": 0.1}),
    ("load_bucket", {"model_kind": "probe_refit", "model_config": SMALL, "step_sizes": {"spindle_rpm": 500.0}})])
def test_a_restored_model_goes_on_exactly_as_the_original(kind, cfg):
    t, temps, y, machine = _plant(n=700)
    model = make_model(kind, cfg)
    _run(model, t, temps, y, machine, stop=500)                  # calibrated and a few compensation probes
    assert model.status(t[499]).phase == "compensation"
    state = json.loads(json.dumps(model.to_state()))
    restored = model_from_state(state)
    assert restored.to_state() == state
    a, pa = _run(model, t, temps, y, machine, start=500)
    b, pb = _run(restored, t, temps, y, machine, start=500)
    assert pa == pb and len(pa) >= 2 and np.array_equal(a[500:], b[500:]) and np.isfinite(a[500:]).all()
