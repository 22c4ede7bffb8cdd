"""The bridge's write path without ROS: limits from the first write, read-back, ramp-down, audit."""
import math

import pytest

from cnc_bridge import bridge_core as bc
from cnc_bridge.audit_log import AuditLog, read_audit_log
from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.error_transform import FIVE_AXIS_COMPONENTS, HtmGeometry
from cnc_bridge.safety_envelope import (LIMIT_ABSOLUTE, LIMIT_DISABLED, LIMIT_RATE, LIMIT_WATCHDOG,
                                        LIMIT_WRITE_FAILED, EnvelopeConfig, SafetyEnvelope)

ORIGIN = {"X": 0.0, "Y": 0.0, "Z": 0.0}


def errors(**values):
    """All seven components, 0 unless given (um, um/m)."""
    return {c: float(values.get(c, 0.0)) for c in FIVE_AXIS_COMPONENTS}


class ScriptedCnc:
    """A backend that records every write and answers what ``answer`` says per axis
    (default: exactly what was written); ``refuse`` makes the next write raise."""

    name = "scripted"

    def __init__(self, held=None):
        self.held = held or {}
        self.writes: list[dict[str, float]] = []
        self.answer = {}
        self.refuse = False
        self.last_error = "timeout"

    def held_state(self):
        return dict(self.held)

    def axis_positions(self):
        return {}

    def write_offsets(self, offsets_um):
        self.writes.append(dict(offsets_um))
        if self.refuse:
            self.refuse = False
            raise ValueError("no offset node for axis 'Z'")
        return {a: self.answer[a](v) if a in self.answer else v for a, v in offsets_um.items()}


class Recorder:
    def __init__(self):
        self.reports: list[tuple[str, str]] = []

    def __call__(self, kind, text):
        self.reports.append((kind, text))

    def kinds(self):
        return [k for k, _ in self.reports]


def make(tmp_path=None, held=None, enabled=True, clock=lambda: 1234.5, **cfg):
    config = dict(abs_limit_um=5.0, max_rate_um_per_s=0.5, max_step_s=10.0, disable_ramp_um_per_s=0.25)
    config.update(cfg)
    cnc = ScriptedCnc(held)
    audit = AuditLog(tmp_path / "audit.csv") if tmp_path is not None else None
    rec = Recorder()
    core = BridgeCore(SafetyEnvelope(EnvelopeConfig(**config), enabled=enabled), cnc, audit,
                      now=clock, report=rec)
    return core, cnc, rec


def by_axis(update):
    return {a.axis: a for a in update.axes}


def test_rate_and_absolute_limit_bind_from_the_first_write():
    core, cnc, _ = make()
    big = errors(E_X0C=12.0, E_Y0C=-1.0, E_Z0T=-20.0)
    first = by_axis(core.update(100.0, big, ORIGIN, fresh=True))
    # nothing written yet, so nothing may move at the first instant: the rate limit binds
    assert cnc.writes == [{"X": 0.0, "Y": 0.0, "Z": 0.0}]
    assert first["X"].commanded_um == 12.0 and first["X"].flags == LIMIT_ABSOLUTE | LIMIT_RATE
    assert first["Y"].flags == LIMIT_RATE and first["Z"].flags == LIMIT_ABSOLUTE | LIMIT_RATE
    second = by_axis(core.update(104.0, big, ORIGIN, fresh=True))
    assert cnc.writes[-1] == {"X": 2.0, "Y": -1.0, "Z": -2.0}       # 0.5 um/s * 4 s, Y reached
    assert second["Y"].flags == 0
    t = 104.0
    for _ in range(3):
        t += 4.0
        core.update(t, big, ORIGIN, fresh=True)
    assert cnc.writes[-1] == {"X": 5.0, "Y": -1.0, "Z": -5.0}        # clamped at +-5 um
    last = by_axis(core.update(t + 4.0, big, ORIGIN, fresh=True))
    assert last["X"].flags == LIMIT_ABSOLUTE and last["X"].applied_um == 5.0
    assert core.last_update_t == t + 4.0


def test_held_offsets_are_adopted_within_the_limit_and_the_first_write_moves_from_them(tmp_path):
    core, cnc, _ = make(tmp_path, held={"X": (4.5, True), "Y": (3.0, False), "Z": (2.0, True)})
    adopted = {a.axis: a for a in core.adopt_held()}
    assert adopted["X"].adopted_um == 4.5 and adopted["X"].flags == 0
    assert adopted["Y"].adopted_um == 0.0 and adopted["Y"].flags == LIMIT_DISABLED
    assert adopted["Z"].adopted_um == 2.0 and adopted["Z"].flags == 0
    assert core.held_refusal is None and core.activate(True) is None
    first = by_axis(core.update(0.0, errors(E_X0C=1.0, E_Y0C=1.0, E_Z0T=1.0), ORIGIN, fresh=True))
    assert cnc.writes == [{"X": 4.5, "Y": 0.0, "Z": 2.0}]            # no jump at the first write
    # the first write of an axis carries what its adoption limited, then never again
    assert first["X"].flags == LIMIT_RATE and first["Y"].flags == LIMIT_DISABLED | LIMIT_RATE
    second = by_axis(core.update(2.0, errors(E_X0C=1.0, E_Y0C=1.0, E_Z0T=1.0), ORIGIN, fresh=True))
    assert cnc.writes[-1] == {"X": 3.5, "Y": 1.0, "Z": 1.0}
    assert second["X"].flags == LIMIT_RATE and second["Y"].flags == 0
    rows = read_audit_log(tmp_path / "audit.csv")
    assert [r["note"] for r in rows[:3]] == [
        "start-up: X: held 4.500 um (compensation on), adopted 4.500 um [none]",
        "start-up: Y: held 3.000 um (compensation off), adopted 0.000 um [disabled]",
        "start-up: Z: held 2.000 um (compensation on), adopted 2.000 um [none]"]
    assert [r["time_s"] for r in rows[:3]] == ["1234.500000"] * 3


def test_a_read_back_that_differs_becomes_the_applied_value():
    core, cnc, _ = make()
    core.update(0.0, errors(E_X0C=4.0), ORIGIN, fresh=True)
    cnc.answer = {"X": lambda v: round(v * 0.999, 6)}                  # the CNC quantises
    x = by_axis(core.update(2.0, errors(E_X0C=4.0), ORIGIN, fresh=True))["X"]
    assert (x.written_um, x.read_back_um, x.applied_um, x.confirmed) == (1.0, 0.999, 0.999, True)
    cnc.answer = {}
    core.update(4.0, errors(E_X0C=4.0), ORIGIN, fresh=True)
    assert cnc.writes[-1]["X"] == pytest.approx(1.999)                 # moves on from the read-back


def test_an_unconfirmed_write_keeps_the_last_confirmed_value_and_is_flagged(tmp_path):
    core, cnc, rec = make(tmp_path)
    core.update(0.0, errors(E_X0C=4.0, E_Y0C=4.0), ORIGIN, fresh=True)
    core.update(2.0, errors(E_X0C=4.0, E_Y0C=4.0), ORIGIN, fresh=True)
    cnc.answer = {"X": lambda v: None}
    axes = by_axis(core.update(4.0, errors(E_X0C=4.0, E_Y0C=4.0), ORIGIN, fresh=True))
    assert cnc.writes[-1]["X"] == 2.0
    assert axes["X"].applied_um == 1.0 and not axes["X"].confirmed
    assert axes["X"].flags == LIMIT_RATE | LIMIT_WRITE_FAILED
    assert axes["Y"].applied_um == 2.0 and axes["Y"].flags == LIMIT_RATE
    assert rec.reports == [(bc.NOT_CONFIRMED, "axis X: write of 2.000 um not confirmed (timeout)")]
    cnc.answer = {}
    core.update(6.0, errors(E_X0C=4.0, E_Y0C=4.0), ORIGIN, fresh=True)
    assert cnc.writes[-1] == {"X": 2.0, "Y": 3.0, "Z": 0.0}            # X retries from 1.0
    rows = [r for r in read_audit_log(tmp_path / "audit.csv") if r["time_s"] == "4.000000"]
    assert [(r["axis"], r["applied_um"], r["confirmed"], r["limits"]) for r in rows] == [
        ("X", "", "0", "rate|write_failed"), ("Y", "2.000000", "1", "rate"), ("Z", "0.000000", "1", "none")]


def test_a_refused_write_leaves_every_axis_unconfirmed():
    core, cnc, rec = make()
    core.update(0.0, errors(E_X0C=4.0), ORIGIN, fresh=True)
    cnc.refuse = True
    axes = core.update(2.0, errors(E_X0C=4.0), ORIGIN, fresh=True).axes
    assert all(a.flags & LIMIT_WRITE_FAILED and a.applied_um == 0.0 for a in axes)
    assert rec.kinds() == [bc.WRITE_FAILED] + [bc.NOT_CONFIRMED] * 3
    assert rec.reports[0][1] == "offsets at t=2.000 not written: no offset node for axis 'Z'"


def test_switched_off_the_offsets_ramp_to_zero_then_writes_stop(tmp_path):
    core, cnc, rec = make(tmp_path, clock=lambda: 77.0)
    core.activate(True)
    assert core.writing
    e = errors(E_X0C=2.0, E_Z0T=-1.0)
    for t in (0.0, 4.0, 8.0):
        core.update(t, e, ORIGIN, fresh=True)
    assert core.envelope.applied == {"X": 2.0, "Y": 0.0, "Z": -1.0}
    assert core.deactivate() is True and core.ramping_down and not core.active
    applied, writing = [], []
    for t in (10.0, 12.0, 14.0, 16.0):
        up = core.update(t, e, ORIGIN, fresh=False)                  # the prediction is ignored
        applied.append((by_axis(up)["X"].applied_um, by_axis(up)["Z"].applied_um))
        writing.append(core.writing)
        assert all(a.flags & LIMIT_DISABLED for a in up.axes) and not up.compensation_enabled
    assert applied == [(1.5, -0.5), (1.0, 0.0), (0.5, 0.0), (0.0, 0.0)]   # 0.25 um/s
    assert writing == [True, True, True, False]
    assert rec.reports == [(bc.RAMP_DONE, "deactivated: every offset is at zero; writes stopped")]
    last = read_audit_log(tmp_path / "audit.csv")[-1]
    assert (last["time_s"], last["axis"], last["note"]) == ("77.000000", "", rec.reports[0][1])
    assert core.deactivate() is False                                 # nothing left to ramp


def test_reactivating_during_the_ramp_follows_the_predictions_again():
    core, cnc, _ = make()
    core.activate(True)
    core.update(0.0, errors(E_X0C=2.0), ORIGIN, fresh=True)
    core.update(4.0, errors(E_X0C=2.0), ORIGIN, fresh=True)
    core.deactivate()
    core.update(6.0, errors(E_X0C=2.0), ORIGIN, fresh=False)
    assert core.envelope.applied["X"] == 1.5
    core.activate(True)
    assert core.active and not core.ramping_down
    core.update(8.0, errors(E_X0C=2.0), ORIGIN, fresh=True)
    assert core.envelope.applied["X"] == 2.0


def test_every_write_is_one_audit_line_per_axis_after_the_publication(tmp_path):
    core, cnc, _ = make(tmp_path)
    path = tmp_path / "audit.csv"
    seen = []

    def publish(update):
        seen.append((update.t_s, len(read_audit_log(path))))

    core.update(10.0, errors(E_X0C=3.0, E_Y0C=-0.25), ORIGIN, fresh=True, publish=publish)
    core.update(12.0, errors(E_X0C=3.0, E_Y0C=-0.25), ORIGIN, fresh=True, publish=publish)
    assert seen == [(10.0, 0), (12.0, 3)]         # published before its own lines were written
    rows = read_audit_log(path)
    assert [(r["time_s"], r["axis"], r["commanded_um"], r["applied_um"], r["confirmed"], r["limits"])
            for r in rows] == [
        ("10.000000", "X", "3.000000", "0.000000", "1", "rate"),
        ("10.000000", "Y", "-0.250000", "0.000000", "1", "rate"),
        ("10.000000", "Z", "0.000000", "0.000000", "1", "none"),
        ("12.000000", "X", "3.000000", "1.000000", "1", "rate"),
        ("12.000000", "Y", "-0.250000", "-0.250000", "1", "none"),
        ("12.000000", "Z", "0.000000", "0.000000", "1", "none")]
    assert all(r["note"] == "" for r in rows)


def test_offsets_follow_the_axis_positions():
    core, cnc, _ = make(abs_limit_um=100.0, max_rate_um_per_s=1000.0)
    e = errors(E_C0C=100.0)                       # 100 um/m zero-position error of C
    core.update(0.0, e, {"X": 200.0, "Y": 0.0, "Z": 0.0}, fresh=True)
    core.update(1.0, e, {"X": 200.0, "Y": 0.0, "Z": 0.0}, fresh=True)
    # rigid convention: w = (0, 0, -E_C0C) 1e-3 um/mm; w x (200, 0, 0) mm = (0, -20, 0) um
    assert cnc.writes[-1] == pytest.approx({"X": 0.0, "Y": -20.0, "Z": 0.0})


def test_a_prediction_that_cannot_be_transformed_holds_and_is_not_fresh():
    core, cnc, rec = make(watchdog_timeout_s=100.0)
    core.update(0.0, errors(E_X0C=2.0), ORIGIN, fresh=True)
    core.update(2.0, errors(E_X0C=2.0), ORIGIN, fresh=True)
    bad = errors(E_X0C=5.0)
    del bad["E_C0C"]
    up = core.update(4.0, bad, ORIGIN, fresh=True)
    assert core.envelope.last_fresh_t == 2.0                   # the watchdog still counts from t=2
    assert by_axis(up)["X"].applied_um == 2.0 and by_axis(up)["X"].commanded_um == 2.0
    assert rec.kinds() == [bc.TRANSFORM_FAILED]
    assert rec.reports[0][1].startswith("offsets at t=4.000: error component 'E_C0C' missing")
    up = core.update(103.0, bad, ORIGIN, fresh=True)
    assert by_axis(up)["X"].flags == LIMIT_WATCHDOG


def test_a_non_finite_command_writes_nothing():
    core, cnc, rec = make()
    core.kinematic = True                         # commands are the components themselves
    core.update(0.0, errors(E_X0C=1.0), {}, fresh=True)
    assert core.update(1.0, errors(E_X0C=math.inf), {}, fresh=True) is None
    assert len(cnc.writes) == 1 and core.last_update_t == 0.0
    assert rec.kinds() == [bc.ENVELOPE_REFUSED]


def test_kinematic_mode_writes_the_components():
    core, cnc, _ = make(abs_limit_um=50.0, max_rate_um_per_s=1000.0)
    core.kinematic = True
    core.update(0.0, errors(E_X0C=3.0, E_C0C=-7.0), {}, fresh=True)
    core.update(1.0, errors(E_X0C=3.0, E_C0C=-7.0), {}, fresh=True)
    assert cnc.writes[-1] == {**errors(), "E_X0C": 3.0, "E_C0C": -7.0}


def test_unknown_positions_are_taken_at_the_htm_origin_with_one_report():
    core, cnc, rec = make(abs_limit_um=100.0, max_rate_um_per_s=1000.0)
    core.htm = HtmGeometry(origin_mm=(100.0, 0.0, 0.0))
    e = errors(E_C0C=100.0)
    for t in (0.0, 1.0, 2.0):
        core.update(t, e, {"Y": 0.0, "Z": 0.0}, fresh=True)
    assert cnc.writes[-1] == pytest.approx({"X": 0.0, "Y": 0.0, "Z": 0.0})   # at the origin: no lever
    assert rec.kinds() == [bc.POSITIONS_ASSUMED]
    assert "['X']" in rec.reports[0][1]
    core.positions_required = True
    core.update(3.0, e, {"Y": 0.0, "Z": 0.0}, fresh=True)
    assert rec.kinds()[-1] == bc.TRANSFORM_FAILED and "axis position 'X' unknown" in rec.reports[-1][1]


def test_nothing_to_write_before_any_axis_is_known():
    core, cnc, _ = make()
    assert core.update(0.0, None, ORIGIN, fresh=False) is None
    assert cnc.writes == [] and core.last_update_t == 0.0
