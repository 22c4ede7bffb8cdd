"""Virtual experiment: replay semantics (residual probing, schedule, metrics, bad input)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from agp_cd_synthetic import lathe_recording
from talc_model.adaptive_model import ModelStatusData
from thermal_eval.replay.virtual_experiment import (ReplayColumns, VirtualExperimentError, plot_virtual_experiment,
                                           run_virtual_experiment)


class EveryNthStepModel:
    """A transparent model for checking the replay: predicts a fixed fraction of the last total
    error it learned and asks for a probe every ``n`` input updates."""

    kind = "probe_log"

    def __init__(self, component: str, n: int, fraction: float = 0.5):
        self.component_names = [component]
        self.n, self.fraction = n, fraction
        self.updates = 0
        self.learned: list[tuple[float, float, float]] = []   # t, measured, applied
        self.total = 0.0
        self.inputs_seen: list[dict] = []

    def update_inputs(self, t_s, temperatures, machine_state):
        self.updates += 1
        self.inputs_seen.append({**temperatures, **machine_state})

    def predict(self, t_s):
        c = self.component_names[0]
        return {c: self.fraction * self.total}, {c: math.nan}

    def probe_due(self, t_s):
        return self.updates % self.n == 1

    def add_measurement(self, t_s, measured, applied_compensation):
        c = self.component_names[0]
        self.learned.append((t_s, measured[c], applied_compensation[c]))
        self.total = measured[c] + applied_compensation[c]

    def add_failed_measurement(self, t_s, reason):
        raise AssertionError(reason)

    def status(self, t_s):
        return ModelStatusData(phase="compensation", probing_cycles=len(self.learned))

    def to_state(self):
        return {}

    @classmethod
    def from_state(cls, state):
        raise AssertionError("the replay never restores a model from its state")


def test_probe_sees_the_residual_and_the_model_sees_every_input():
    rec = lathe_recording(hours=4.0, dt=120.0, seed=0, oil_step_h=None)
    model = EveryNthStepModel("GB_X", n=10)
    res = run_virtual_experiment(rec, model)
    gb = rec.columns["GB_X_um"] - rec.columns["GB_X_um"][0]
    assert model.updates == len(rec)
    # sensors by id (column minus "_c") and machine inputs; error columns are never inputs
    assert set(model.inputs_seen[0]) == {"tool", "spindle", "oil", "ambient", "holder", "spindle_rpm"}
    assert len(model.learned) == len(res.probe_times_s) == math.ceil(len(rec) / 10)
    for t, measured, applied in model.learned:
        k = int(np.searchsorted(rec.time_s, t))
        assert measured + applied == pytest.approx(gb[k])          # residual + compensation = total
        assert applied == pytest.approx(res.predicted["GB_X"][k])
    np.testing.assert_allclose(res.residual["GB_X"], gb - res.predicted["GB_X"])
    m = res.metrics["GB_X"]
    rms_u = float(np.sqrt(np.mean(gb ** 2)))
    assert m["rms_uncompensated_um"] == pytest.approx(rms_u)
    assert m["rms_reduction_pct"] == pytest.approx(100 * (1 - np.sqrt(np.mean(res.residual["GB_X"] ** 2)) / rms_u))


def test_probe_noise_and_resolution_are_applied_deterministically():
    rec = lathe_recording(hours=2.0, dt=120.0, seed=1, oil_step_h=None)
    runs = []
    for _ in range(2):
        model = EveryNthStepModel("GB_X", n=3)
        run_virtual_experiment(rec, model, probe_noise_um=0.3, probe_resolution_um=0.1, seed=7)
        runs.append([m for _, m, _ in model.learned])
    assert runs[0] == runs[1]
    assert all(abs(m / 0.1 - round(m / 0.1)) < 1e-9 for m in runs[0])


def test_only_the_probed_components_are_measured(tmp_path):
    rec = lathe_recording(hours=2.0, dt=120.0, seed=2, oil_step_h=None)
    model = EveryNthStepModel("T02_X", n=5)
    with pytest.raises(VirtualExperimentError, match="probed component 'XX'"):
        run_virtual_experiment(rec, model, probed_components=["XX"])
    res = run_virtual_experiment(rec, model, probed_components=["T02_X"])
    plot_virtual_experiment(res, tmp_path / "replay.png", title="synthetic", sigma_max=1.0)
    assert (tmp_path / "replay.png").stat().st_size > 1000


def test_bad_columns_are_named():
    rec = lathe_recording(hours=1.0, dt=120.0, seed=3, oil_step_h=None)
    with pytest.raises(VirtualExperimentError, match="'E_X0C' has no error column"):
        run_virtual_experiment(rec, EveryNthStepModel("E_X0C", n=5))
    cols = ReplayColumns.from_recording(rec)
    cols.sensors["ghost"] = "ghost_c"
    with pytest.raises(VirtualExperimentError, match="'ghost_c'"):
        run_virtual_experiment(rec, EveryNthStepModel("GB_X", n=5), columns=cols)
    with pytest.raises(VirtualExperimentError, match="empty range"):
        run_virtual_experiment(rec, EveryNthStepModel("GB_X", n=5), start=10, stop=10)
