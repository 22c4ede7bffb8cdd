"""Clamp, rate limit, watchdog (hold, then ramp to zero), enable/disable, audit log."""
import math

import pytest

from cnc_bridge import safety_envelope as se
from cnc_bridge.audit_log import AuditLog, read_audit_log
from cnc_bridge.safety_envelope import EnvelopeConfig, EnvelopeConfigError, SafetyEnvelope


def run(env, t, cmd=None, fresh=False):
    """One step, with the CNC confirming exactly what was asked (ideal backend)."""
    out = {d.axis: d for d in env.step(t, cmd, fresh)}
    for d in out.values():
        env.confirm(d.axis, d.applied_um)
    return out


def test_flags_match_the_axis_offsets_message():
    from thermal_comp_msgs.msg import AxisOffsets
    assert (se.LIMIT_ABSOLUTE, se.LIMIT_RATE, se.LIMIT_WATCHDOG, se.LIMIT_DISABLED,
            se.LIMIT_WRITE_FAILED) == (AxisOffsets.LIMIT_ABSOLUTE, AxisOffsets.LIMIT_RATE,
                                       AxisOffsets.LIMIT_WATCHDOG, AxisOffsets.LIMIT_DISABLED,
                                       AxisOffsets.LIMIT_WRITE_FAILED)


def test_absolute_clamp_per_axis():
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=20.0, axis_abs_limits_um={"Z": 5.0},
                                        max_rate_um_per_s=1000.0))
    run(env, 0.0, {"X": 50.0, "Y": -50.0, "Z": 8.0}, fresh=True)
    out = run(env, 1.0, {"X": 50.0, "Y": -50.0, "Z": 8.0}, fresh=True)
    assert out["X"].applied_um == 20.0 and out["X"].flags == se.LIMIT_ABSOLUTE
    assert out["Y"].applied_um == -20.0 and out["Y"].flags == se.LIMIT_ABSOLUTE
    assert out["Z"].applied_um == 5.0 and out["Z"].commanded_um == 8.0
    out = run(env, 2.0, {"X": 3.0, "Y": 0.0, "Z": -1.0}, fresh=True)
    assert out["X"].applied_um == 3.0 and out["X"].flags == se.LIMIT_NONE


def test_rate_limit_never_exceeded_and_long_pauses_do_not_license_jumps():
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=100.0, max_rate_um_per_s=2.0, max_step_s=5.0))
    run(env, 0.0, {"X": 30.0}, fresh=True)
    assert env.applied["X"] == 0.0                    # no time has passed yet
    out = run(env, 1.0, {"X": 30.0}, fresh=True)
    assert out["X"].applied_um == 2.0 and out["X"].flags == se.LIMIT_RATE
    out = run(env, 101.0, {"X": 30.0}, fresh=True)    # 100 s pause: capped at max_step_s
    assert out["X"].applied_um == 2.0 + 2.0 * 5.0
    prev, t = env.applied["X"], 101.0
    while env.applied["X"] < 30.0:
        t += 0.7
        run(env, t, {"X": 30.0}, fresh=True)
        assert env.applied["X"] - prev <= 2.0 * 0.7 + 1e-12
        prev = env.applied["X"]
    assert env.applied["X"] == 30.0
    assert run(env, t + 1, {"X": 30.0}, fresh=True)["X"].flags == se.LIMIT_NONE


def test_time_going_backwards_moves_nothing():
    env = SafetyEnvelope(EnvelopeConfig(max_rate_um_per_s=1.0))
    run(env, 10.0, {"X": 5.0}, fresh=True)
    run(env, 12.0, {"X": 5.0}, fresh=True)
    assert env.applied["X"] == 2.0
    run(env, 3.0, {"X": 5.0}, fresh=True)
    assert env.applied["X"] == 2.0


def test_watchdog_holds_then_ramps_to_zero():
    cfg = EnvelopeConfig(abs_limit_um=50.0, max_rate_um_per_s=10.0, watchdog_timeout_s=10.0,
                         watchdog_hold_s=5.0, watchdog_ramp_um_per_s=1.0)
    env = SafetyEnvelope(cfg)
    run(env, 0.0, {"X": 8.0}, fresh=True)
    run(env, 1.0, {"X": 8.0}, fresh=True)
    assert env.applied["X"] == 8.0
    for t in range(2, 11):                            # within the timeout: normal, no flag
        out = run(env, float(t), None)
        assert out["X"].flags == se.LIMIT_NONE and out["X"].applied_um == 8.0
    for t in range(12, 17):                           # timeout at 11 s, hold until 16 s
        out = run(env, float(t), {"X": 20.0})         # recomputed command, not fresh: ignored
        assert out["X"].flags == se.LIMIT_WATCHDOG and out["X"].applied_um == 8.0
    out = run(env, 17.0)                              # ramp at 1 um/s
    assert out["X"].applied_um == 7.0 and out["X"].flags == se.LIMIT_WATCHDOG
    t = 17.0
    while env.applied["X"] > 0:
        t += 1.0
        run(env, t)
    assert t == 24.0
    out = run(env, 25.0, {"X": 4.0}, fresh=True)      # a fresh prediction ends the watchdog
    assert out["X"].flags == se.LIMIT_NONE and out["X"].applied_um == 4.0


def test_watchdog_ramp_zero_means_hold_forever():
    env = SafetyEnvelope(EnvelopeConfig(max_rate_um_per_s=10.0, watchdog_timeout_s=1.0,
                                        watchdog_hold_s=0.0, watchdog_ramp_um_per_s=0.0))
    run(env, 0.0, {"Y": 6.0}, fresh=True)
    run(env, 1.0, {"Y": 6.0}, fresh=True)
    for t in range(2, 50, 7):
        assert run(env, float(t))["Y"].applied_um == 6.0


def test_before_the_first_prediction_nothing_is_applied_and_watchdog_is_flagged():
    env = SafetyEnvelope()
    env.add_axes(["X", "Y", "Z"])
    out = run(env, 5.0)
    assert all(d.applied_um == 0.0 and d.flags == se.LIMIT_WATCHDOG and math.isnan(d.commanded_um)
               for d in out.values())


def test_disable_ramps_to_zero_and_enable_ramps_back_up():
    env = SafetyEnvelope(EnvelopeConfig(max_rate_um_per_s=2.0, disable_ramp_um_per_s=4.0))
    run(env, 0.0, {"Z": 10.0}, fresh=True)
    for t in range(1, 6):
        run(env, float(t), {"Z": 10.0}, fresh=True)
    assert env.applied["Z"] == 10.0
    env.set_enabled(False)
    out = run(env, 6.0, {"Z": 10.0}, fresh=True)
    assert out["Z"].applied_um == 6.0 and out["Z"].flags == se.LIMIT_DISABLED
    run(env, 7.0, {"Z": 10.0}, fresh=True)
    out = run(env, 8.0, {"Z": 10.0}, fresh=True)
    assert out["Z"].applied_um == 0.0 and out["Z"].flags == se.LIMIT_DISABLED
    env.set_enabled(True)
    out = run(env, 9.0, {"Z": 10.0}, fresh=True)
    assert out["Z"].applied_um == 2.0 and out["Z"].flags == se.LIMIT_RATE


def test_failed_write_keeps_the_last_confirmed_value():
    env = SafetyEnvelope(EnvelopeConfig(max_rate_um_per_s=1.0))
    run(env, 0.0, {"X": 5.0}, fresh=True)
    run(env, 1.0, {"X": 5.0}, fresh=True)
    d = env.step(2.0, {"X": 5.0}, True)[0]
    assert d.applied_um == 2.0
    env.confirm("X", None)                            # the CNC did not confirm
    assert env.applied["X"] == 1.0
    assert env.step(3.0, {"X": 5.0}, True)[0].applied_um == 2.0   # still at most 1 um/s


def test_bad_input_names_the_axis_and_changes_nothing():
    env = SafetyEnvelope()
    run(env, 0.0, {"X": 1.0}, fresh=True)
    with pytest.raises(ValueError, match="'Y'.*nan"):
        env.step(1.0, {"X": 2.0, "Y": float("nan")}, True)
    assert env.last_fresh_t == 0.0 and "Y" not in env.applied
    with pytest.raises(EnvelopeConfigError, match="max_rate_um_per_s"):
        EnvelopeConfig(max_rate_um_per_s=0.0)
    with pytest.raises(EnvelopeConfigError, match="axis_abs_limits_um.X"):
        EnvelopeConfig(axis_abs_limits_um={"X": -1.0})


def test_audit_log_is_append_only_one_line_per_axis_write(tmp_path):
    path = tmp_path / "audit" / "writes.csv"
    log = AuditLog(path)
    log.log_write(1.5, [("X", 3.0, 2.0, se.LIMIT_RATE), ("Y", 1.0, None, se.LIMIT_WRITE_FAILED)])
    log.close()
    log = AuditLog(path)                              # reopened: appended, no second header
    log.log_write(2.5, [("X", 40.0, 30.0, se.LIMIT_ABSOLUTE | se.LIMIT_RATE)])
    rows = read_audit_log(path)                       # readable while still open (flushed)
    log.close()
    assert [(r["time_s"], r["axis"], r["applied_um"], r["confirmed"], r["limits"]) for r in rows] == [
        ("1.500000", "X", "2.000000", "1", "rate"),
        ("1.500000", "Y", "", "0", "write_failed"),
        ("2.500000", "X", "30.000000", "1", "absolute|rate")]


# ---------------------------------------------------------------------------------------
# Invariants over random command sequences (hypothesis; derandomized, so deterministic).
from hypothesis import given, settings, strategies as st  # noqa: E402

_step = st.tuples(st.floats(0.0, 30.0),                               # dt, s
                  st.one_of(st.none(), st.floats(-200.0, 200.0)),     # new command (None: none)
                  st.booleans(),                                      # enabled
                  st.booleans())                                      # write confirmed


@settings(max_examples=150, deadline=None, derandomize=True)
@given(steps=st.lists(_step, min_size=1, max_size=60))
def test_envelope_invariants_hold_for_any_sequence(steps):
    cfg = EnvelopeConfig(abs_limit_um=25.0, max_rate_um_per_s=1.5, max_step_s=4.0,
                         watchdog_timeout_s=20.0, watchdog_hold_s=10.0,
                         watchdog_ramp_um_per_s=0.5, disable_ramp_um_per_s=2.0)
    fastest = max(cfg.max_rate_um_per_s, cfg.disable_ramp_um_per_s, cfg.watchdog_ramp_um_per_s)
    env = SafetyEnvelope(cfg)
    env.add_axes(["X"])
    t, prev = 0.0, 0.0
    for dt, cmd, enabled, confirmed in steps:
        t += dt
        env.set_enabled(enabled)
        (d,) = env.step(t, {"X": cmd} if cmd is not None else None, fresh=cmd is not None)
        # never beyond the absolute limit, never faster than the fastest allowed ramp
        assert abs(d.applied_um) <= cfg.abs_limit_um + 1e-9
        assert abs(d.applied_um - prev) <= fastest * min(dt, cfg.max_step_s) + 1e-9
        # disabled or watchdog: never moves away from zero
        if d.flags & (se.LIMIT_DISABLED | se.LIMIT_WATCHDOG):
            assert abs(d.applied_um) <= abs(prev) + 1e-9
        if d.flags & se.LIMIT_ABSOLUTE:
            assert abs(d.commanded_um) > cfg.abs_limit_um
        env.confirm("X", d.applied_um if confirmed else None)
        prev = env.applied["X"]


@pytest.mark.parametrize("held, on, adopted, flags, refused", [
    (5000.0, True, 5000.0, se.LIMIT_ABSOLUTE, "beyond the absolute limit 30 um"),  # 5 mm applied
    (1e9, True, 1e9, se.LIMIT_ABSOLUTE, "beyond the absolute limit 30 um"),        # absurd
    (-5000.0, False, 0.0, se.LIMIT_DISABLED, ""),       # held with compensation off: counts as 0
    (math.inf, True, 0.0, se.LIMIT_ABSOLUTE, "not a finite offset"),
    (12.0, True, 12.0, se.LIMIT_NONE, ""),              # within the envelope: kept
])
def test_held_offsets_are_adopted_only_within_the_envelope(held, on, adopted, flags, refused):
    """Within the envelope a held offset is adopted; one applied beyond it is refused, never
    clamped (a clamp is one write of the whole difference), and counts as applied as it is."""
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=30.0, max_rate_um_per_s=0.5, max_step_s=10.0))
    [a] = env.adopt_held({"X": held}, {"X": on})
    assert (a.held_um, a.adopted_um, a.flags) == (held, adopted, flags)
    assert (refused in a.refused) and bool(a.refused) == bool(refused)
    assert env.applied["X"] == adopted
    assert f"held {held:.3f}" in a.describe()
    assert (refused or f"adopted {adopted:.3f}") in a.describe()
    # the first steps move at most the rate limit away from what counts as applied
    run(env, 0.0, {"X": -30.0}, fresh=True)
    out = run(env, 1.0, {"X": -30.0}, fresh=True)
    assert out["X"].applied_um == pytest.approx(adopted - 0.5)


def test_start_with_5mm_held_and_compensation_off_never_jumps():
    """The CNC held X = -5 mm with compensation off; every write after start-up stays
    within rate * dt of zero."""
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=30.0, max_rate_um_per_s=0.5, max_step_s=10.0))
    env.adopt_held({"X": -5000.0}, {"X": False})
    prev = 0.0
    for k in range(0, 200):
        out = run(env, float(k), {"X": -20.0}, fresh=True)
        assert abs(out["X"].applied_um - prev) <= 0.5 + 1e-12
        assert abs(out["X"].applied_um) <= 30.0
        prev = out["X"].applied_um
    assert prev == pytest.approx(-20.0)


def test_a_limit_changed_at_runtime_applies_to_the_next_step():
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=30.0, max_rate_um_per_s=100.0, max_step_s=10.0))
    run(env, 0.0, {"X": 0.0}, fresh=True)
    env.reconfigure(EnvelopeConfig(abs_limit_um=1.0, max_rate_um_per_s=100.0, max_step_s=10.0))
    out = run(env, 1.0, {"X": 20.0}, fresh=True)
    assert out["X"].applied_um == 1.0 and out["X"].flags & se.LIMIT_ABSOLUTE
    with pytest.raises(EnvelopeConfigError, match="abs_limit_um"):
        EnvelopeConfig(abs_limit_um=-1.0)


def test_only_tightening_is_allowed_while_active():
    from cnc_bridge.bridge_params import loosening
    current = {"abs_limit_um": 30.0, "max_rate_um_per_s": 0.5, "watchdog_ramp_um_per_s": 0.05}
    assert loosening({"abs_limit_um": 1.0}, current) is None
    assert loosening({"max_rate_um_per_s": 0.1}, current) is None
    assert "widens" in loosening({"abs_limit_um": 31.0}, current)
    assert "max_rate_um_per_s" in loosening({"max_rate_um_per_s": 5.0}, current)
    assert "watchdog_ramp_um_per_s" in loosening({"watchdog_ramp_um_per_s": 0.0}, current)
    assert loosening({"enable": False}, current) is None
