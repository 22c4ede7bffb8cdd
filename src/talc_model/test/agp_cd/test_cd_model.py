"""Characteristic-diagram model behind the AdaptiveModel protocol (kind "cd")."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agp_cd_synthetic import lathe_recording
from talc_model.adaptive_model import AdaptiveModel, make_model, model_from_state
from talc_model.cd.model import CdModelError, CharacteristicDiagramModel
from thermal_eval.replay.virtual_experiment import run_virtual_experiment

CFG = {"components": ["GB_X"], "calibration_probe_interval_s": 600.0, "min_calibration_s": 4 * 3600.0,
       "update_probe_interval_s": 1800.0, "update_batch": 4}


def test_cd_model_calibrates_then_updates_and_compensates():
    rec = lathe_recording(hours=24.0, dt=120.0, seed=11, oil_step_h=14.0, oil_step_c=8.0)
    model = CharacteristicDiagramModel(CFG)
    assert isinstance(model, AdaptiveModel)
    res = run_virtual_experiment(rec, model, probed_components=["GB_X"])
    st = model.status(float(rec.time_s[-1]))
    assert st.phase == "compensation"
    assert st.parameter_updates >= 2                      # base fit plus load-case updates
    assert 1 <= len(model.inputs["GB_X"]) <= 3
    assert math.isfinite(st.max_uncertainty)
    assert res.metrics["GB_X"]["rms_reduction_pct"] > 70
    # probes are sparse after calibration: one per update interval
    after = [t for t in res.probe_times_s if t > 4 * 3600.0 + 600.0]
    assert np.all(np.diff(after) >= 1800.0 - 1e-6)


def test_cd_model_state_round_trip_and_registry():
    rec = lathe_recording(hours=10.0, dt=120.0, seed=12, oil_step_h=None)
    model = make_model("cd", CFG)
    half = len(rec) // 2 + 37
    run_virtual_experiment(rec, model, probed_components=["GB_X"], stop=half)
    assert model.phase == "compensation"
    back = model_from_state(json.loads(json.dumps(model.to_state())))
    assert isinstance(back, CharacteristicDiagramModel)
    for k in range(half, len(rec)):
        t = float(rec.time_s[k])
        temps = {c[:-2]: float(rec.columns[c][k]) for c in rec.names("sensor")}
        for m in (model, back):
            m.update_inputs(t, temps, {})
        assert model.predict(t) == back.predict(t)
        assert model.probe_due(t) == back.probe_due(t)
    assert back.status(t).as_dict() == model.status(t).as_dict()


def test_cd_model_bad_config_and_input_are_named():
    with pytest.raises(CdModelError, match="unknown key"):
        CharacteristicDiagramModel({"grid": 3})
    with pytest.raises(CdModelError, match="update_batch"):
        CharacteristicDiagramModel({"update_batch": 0})
    m = CharacteristicDiagramModel(CFG)
    with pytest.raises(CdModelError, match="no inputs yet"):
        m.add_measurement(0.0, {"GB_X": 1.0}, {})
    m.update_inputs(0.0, {"a": 20.0}, {})
    m.add_measurement(0.0, {"other": 1.0}, {})
    assert m.status(0.0).failed_probing_cycles == 1 and m.status(0.0).probing_cycles == 0
