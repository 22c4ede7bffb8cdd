"""Load-driven probing wrapper: dense probings after a load change, on top of the model's own schedule."""
import math

import pytest

from talc_model.adaptive_model import ModelStatusData
from talc_model.probing.load_driven import LoadDrivenProbing


class EveryTwoHours:
    """Test double of an adaptive model: probes every 2 h, records what it is given."""

    kind = "double"
    component_names = ["ch1"]

    def __init__(self):
        self.last = -math.inf
        self.measured_at: list[float] = []

    def update_inputs(self, t_s, temperatures, machine_state):
        pass

    def predict(self, t_s):
        return {"ch1": 0.0}, {"ch1": math.nan}

    def probe_due(self, t_s):
        return t_s - self.last >= 7200.0

    def add_measurement(self, t_s, measured, applied_compensation):
        self.last = t_s
        self.measured_at.append(t_s)

    def add_failed_measurement(self, t_s, reason):
        self.last = t_s

    def status(self, t_s):
        return ModelStatusData(phase="compensation", probing_cycles=len(self.measured_at),
                               next_probing_due_s=self.last + 7200.0)

    def to_state(self):
        return {"kind": self.kind, "last": self.last}


def _replay(model, hours=8.0, step=15.0, change_at=(3600.0 * 3, 3600.0 * 3.5)):
    t, probes, rpm = 0.0, [], 0.0
    while t < hours * 3600.0:
        if any(abs(t - c) < step / 2 for c in change_at):
            rpm += 1000.0
        model.update_inputs(t, {"t1": 20.0}, {"spindle_rpm": rpm})
        model.predict(t)
        if model.probe_due(t):
            model.add_measurement(t, {"ch1": 0.0}, {"ch1": 0.0})
            probes.append(t)
        t += step
    return probes


def test_a_load_change_adds_twelve_dense_probings_and_one_inside_the_phase_is_ignored():
    inner = EveryTwoHours()
    wrapped = LoadDrivenProbing(inner, interval_s=600.0, measurements=12, probe_duration_s=95.0)
    probes = _replay(wrapped)
    plain = _replay(EveryTwoHours())
    assert wrapped.load_phases == 1                       # the second change falls inside the phase
    dense = [p for p in probes if 3 * 3600.0 < p < 3 * 3600.0 + 12 * 720.0]
    assert len(dense) == 12
    assert dense[0] - 3 * 3600.0 == pytest.approx(600.0, abs=15.0)
    # 10 min from the end of each 95-s cycle; the model's own 2-h clock restarts at each probing
    assert all(695.0 <= b - a < 695.0 + 15.0 for a, b in zip(dense, dense[1:]))
    after = [p for p in probes if p > dense[-1]]
    assert not after or after[0] - dense[-1] >= 7200.0
    assert len(probes) > len(plain)
    assert inner.measured_at == probes                    # every probing reaches the wrapped model
    assert wrapped.status(probes[-1]).probing_cycles == len(probes)


def test_no_change_no_extra_probing_and_bad_settings_are_named():
    wrapped = LoadDrivenProbing(EveryTwoHours())
    assert _replay(wrapped, change_at=()) == _replay(EveryTwoHours(), change_at=())
    assert wrapped.load_phases == 0
    with pytest.raises(ValueError, match="interval_s"):
        LoadDrivenProbing(EveryTwoHours(), interval_s=0.0)
    with pytest.raises(ValueError, match="measurements"):
        LoadDrivenProbing(EveryTwoHours(), measurements=0)
