"""Sensor and probing faults in the closed loop of the pure cores (no ROS): twin -> sensor
status -> TALC -> offsets -> safety envelope. Policies: docs/reliability.md."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thermal_eval.reliability import fault_injection as fi
H = 3600.0
HOURS = 24.0
RATE = 0.005          # um/s: 1.5 um per 5-min step, so the rate limit really binds
STALE_AFTER_S = 1800.0  # nmv5000_sensors.yaml
FAULTS = [fi.SensorFault("ambient", "nan", 10 * H, 12 * H),
          fi.SensorFault("ws_mwf", "out_of_range", 13 * H, 14 * H, value=95.0),
          fi.SensorFault("c_coolant_delta", "stuck", 15 * H, 18 * H),
          fi.SensorFault("ws_mwf", "spike", 19 * H, 19 * H + 300.0, value=8.0),
          fi.SensorFault("ambient", "disappear", 20 * H, 21 * H)]
PROBE_FAILURES = [8 * H, 12 * H, 16 * H]


@pytest.fixture(scope="module")
def runs():
    clean = fi.run_core_loop(hours=HOURS, max_rate_um_per_s=RATE)
    faulty = fi.run_core_loop(FAULTS, hours=HOURS, max_rate_um_per_s=RATE, probe_failures=PROBE_FAILURES)
    return clean, faulty


def _window(res, f):
    return np.flatnonzero((res.t_s >= f.t_start_s) & (res.t_s < f.t_end_s))


@pytest.mark.parametrize("fault, expected", [(FAULTS[0], 3), (FAULTS[1], 2), (FAULTS[4], 3)],
                         ids=["nan", "out_of_range", "disappear"])
def test_bad_readings_are_flagged_and_excluded_at_once(runs, fault, expected):
    _, res = runs
    idx = _window(res, fault)
    assert idx.size >= 12
    assert np.all(res.status[fault.sensor_id][idx] == expected)
    assert all(fault.sensor_id in res.excluded[i] for i in idx)
    after = np.flatnonzero(res.t_s >= fault.t_end_s + 300.0)[:3]   # back to ok once the fault ends
    assert np.all(res.status[fault.sensor_id][after] == 0)


def test_a_stuck_sensor_is_flagged_stale_after_the_configured_time(runs):
    _, res = runs
    f = FAULTS[2]
    idx = _window(res, f)
    age = res.t_s[idx] - f.t_start_s
    st_ = res.status[f.sensor_id][idx]
    assert np.all(st_[age > STALE_AFTER_S + 300.0] == 1)          # STALE, and excluded
    assert all(f.sensor_id in res.excluded[i] for i in idx[age > STALE_AFTER_S + 300.0])


def test_every_fault_was_injected(runs):
    _, res = runs
    assert all(n > 0 for n in res.injected_per_fault), res.injected_per_fault


def test_predictions_go_on_through_the_faults(runs):
    clean, res = runs
    for c in res.components:
        expect = np.isfinite(clean.predicted[c])
        assert np.all(np.isfinite(res.predicted[c][expect])), c


def test_offsets_never_move_faster_than_the_rate_limit(runs):
    clean, res = runs
    for r in (clean, res):
        assert fi.offset_violations(r.t_s, r.applied_um, RATE, 30.0, 600.0) == []
    assert any(np.any(fl & 2) for fl in res.flags.values())          # the limit did bind


def test_failed_probing_cycles_are_counted_never_learned_and_the_schedule_goes_on(runs):
    clean, res = runs
    assert res.failed_probing_cycles == len(PROBE_FAILURES)
    assert clean.failed_probing_cycles == 0
    assert res.probing_cycles > 0


# ------------------------------------------------------------------ probing cycle faults
@pytest.mark.parametrize("fault, value, says", [("outlier", 25.0, "RMS residual"),
                                                ("missing_trigger", 0.0, "missing trigger"),
                                                ("error", 0.0, "failed"),
                                                ("slow", 1000.0, "timeout")])
def test_a_bad_cycle_fails_with_no_errors(fault, value, says):
    from probe_cycle.probe_backend import ArtefactModelBackend
    from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine
    from thermal_twin.machine.artefact_geometry import ArtefactGeometry
    engine = ProbeCycleEngine(ArtefactGeometry())
    assert engine.run(GoalSpec(set_reference=True), ArtefactModelBackend(errors={"E_X0C": 3.0})).success
    r = engine.run(GoalSpec(), fi.FaultyProbeBackend(ArtefactModelBackend(errors={"E_X0C": 3.0}), fault,
                                                      value_um=value))
    assert not r.success and r.errors is None
    assert says in r.message
    good = engine.run(GoalSpec(), ArtefactModelBackend(errors={"E_X0C": 3.0}))
    assert good.success                           # the reference survived the bad cycle


def test_a_failed_cycle_does_not_move_the_model_nor_start_a_no_good_phase():
    """The no-good logic only sees cycles that passed the probe's own checks: a rejected
    outlier reaches TALC as a failure, which changes nothing but the counter and the schedule."""
    clean = fi.run_core_loop(hours=10.0)
    t_end = float(clean.t_s[-1])
    model_a, model_b = _replay_model(clean), _replay_model(clean)
    before = model_b.status(t_end)
    model_b.add_failed_measurement(t_end, "outlier fit rejected by the cycle (RMS residual)")
    assert model_a.predict(t_end) == model_b.predict(t_end)
    sa, sb = model_a.status(t_end), model_b.status(t_end)
    assert sb.failed_probing_cycles == before.failed_probing_cycles + 1
    assert (sb.no_good_phases, sb.phase, sb.probing_cycles, sb.parameter_updates) == \
        (sa.no_good_phases, sa.phase, sa.probing_cycles, sa.parameter_updates)
    assert sb.next_probing_due_s > t_end               # the schedule retries later, not at once


def _replay_model(res):
    """A TALC model fed the loop's temperatures and true errors (probing when due)."""
    import importlib.resources

    import yaml

    from talc_model.adaptive_model import make_model
    cfg = yaml.safe_load((importlib.resources.files("talc_model") / "config" / "talc_nmv5000.yaml").read_text())
    m = make_model("talc", cfg)
    ids = list(res.status)
    for i, t in enumerate(res.t_s):
        m.update_inputs(t, {s: 20.0 + 0.01 * i if s == "ambient" else 20.0 + 0.005 * i for s in ids}, {})
        m.predict(t)
        if m.probe_due(t):
            m.add_measurement(t, {c: float(res.true[c][i]) for c in res.components}, {})
    return m


# ------------------------------------------------------------------ the envelope, any input
@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(0.0, 700.0), st.one_of(st.floats(-1e4, 1e4), st.just(math.nan)),
                          st.booleans(), st.booleans()), min_size=1, max_size=40))
def test_the_envelope_never_lets_an_offset_move_faster_than_the_rate_limit(steps):
    """Spikes, NaN commands, long pauses, enable toggles: the applied offset moves at most
    max_rate * min(dt, max_step) per step and never beyond the absolute limit."""
    from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
    cfg = EnvelopeConfig(abs_limit_um=30.0, max_rate_um_per_s=0.05, max_step_s=60.0, watchdog_timeout_s=900.0,
                         disable_ramp_um_per_s=0.05)
    env = SafetyEnvelope(cfg)
    t, times, applied = 0.0, [], []
    for dt, cmd, fresh, enabled in steps:
        t += dt
        env.set_enabled(enabled)
        try:
            out = env.step(t, {"X": cmd}, fresh=fresh)
        except ValueError:
            assert not math.isfinite(cmd)             # refused NaN: nothing changed
            continue
        for d in out:
            env.confirm(d.axis, d.applied_um)
            times.append(t)
            applied.append(d.applied_um)
    assert fi.offset_violations(times, {"X": applied}, cfg.max_rate_um_per_s, cfg.abs_limit_um,
                                cfg.max_step_s) == []


def test_the_offset_check_catches_a_jump():
    v = fi.offset_violations([0.0, 10.0, 20.0], {"X": [0.0, 0.5, 8.0]}, 0.1, 30.0, 600.0)
    assert len(v) == 1 and v[0].t_s == 20.0 and v[0].why == "rate limit"
    v = fi.offset_violations([0.0, 100.0], {"X": [0.0, 40.0]}, 0.1, 30.0, 600.0)
    assert {x.why for x in v} == {"absolute limit", "rate limit"}


def test_late_frames_arrive_out_of_order_but_complete():
    order = fi.reorder_late(6, {1: 2, 4: 1})
    assert sorted(order) == list(range(6)) and order.index(1) > order.index(3)
