"""Activation against an offset the CNC applies beyond the envelope: refused, never a jump.

Every write checked: a step from what the CNC applied before (the held offset included)
beyond ``max_rate * dt`` or a value beyond the absolute limit is an unsafe write.
"""
from __future__ import annotations

import logging

import pytest

from cnc_bridge import bridge_core as bc
from cnc_bridge.audit_log import AuditLog, read_audit_log
from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.cnc_emulator import CncEmulatorThread, EmulatorConfig, EmulatorState
from cnc_bridge.opcua_backend import OpcUaBackend
from cnc_bridge.opcua_config import OpcUaConfig, default_node_map
from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope

from test_bridge_core import ORIGIN, Recorder, ScriptedCnc, errors
from test_opcua_backend import port  # noqa: F401

logging.getLogger("asyncua").setLevel(logging.ERROR)

LIMIT, RATE, DT = 30.0, 0.5, 10.0


def core_for(backend, audit=None, rec=None):
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=LIMIT, max_rate_um_per_s=RATE, max_step_s=DT),
                         enabled=False)
    return BridgeCore(env, backend, audit, now=lambda: 7.0, report=rec)


def unsafe_steps(values_um, start_um):
    """Writes that step beyond one update's rate allowance or exceed the absolute limit."""
    out, prev = [], start_um
    for v in values_um:
        if abs(v - prev) > RATE * DT + 1e-9 or abs(v) > LIMIT + 1e-9:
            out.append((prev, v))
        prev = v
    return out


def drive(core, cnc, t0=0.0, n=12, target=20.0):
    """What the node does while the core writes: one update per prediction, DT apart."""
    for k in range(n):
        if core.writing:
            core.update(t0 + k * DT, errors(E_X0C=target), ORIGIN, fresh=True)


def test_five_mm_held_with_compensation_on_refuses_activation_and_writes_nothing(tmp_path):
    cnc = ScriptedCnc({"X": (-5000.0, True), "Y": (3.0, True), "Z": (0.0, False)})
    rec = Recorder()
    core = core_for(cnc, AuditLog(tmp_path / "audit.csv"), rec)
    core.adopt_held()
    line = core.activate(True)
    assert line is not None and "\n" not in line
    assert line.startswith("activate refused: the CNC applies X = -5000.000 um, beyond the "
                           "absolute limit 30 um")
    assert "nothing written" in line and "configure again" in line
    assert not core.active and not core.writing
    assert rec.kinds() == [bc.ACTIVATION_REFUSED] and rec.reports[0][1] == line
    drive(core, cnc)
    assert cnc.writes == [], "refused: not one write"
    assert core.activate(False) is not None, "disabled compensation does not bypass the refusal"
    assert core.counters.activations_refused == 2 and core.counters.writes == 0
    notes = [r["note"] for r in read_audit_log(tmp_path / "audit.csv")]
    assert notes[0].startswith("start-up: X: held -5000.000 um (compensation on), beyond the absolute")
    assert notes[1] == "start-up: Y: held 3.000 um (compensation on), adopted 3.000 um [none]"
    assert notes[3] == line and notes[4] == line         # the audit says it was refused, twice


def test_restarts_bridge_then_cnc_then_the_operator_acts():
    """Bridge restart: continues from what the CNC holds, no step. CNC restarted holding
    -5 mm with compensation on: refused. The operator switches the axis' compensation off
    and configures again: the ramp starts from 0. Every write of every start-up is checked."""
    cnc = ScriptedCnc({"X": (0.0, True)})
    first = core_for(cnc)
    first.adopt_held()
    assert first.activate(True) is None
    drive(first, cnc, n=3)                               # 0, 5, 10 um
    assert unsafe_steps([w["X"] for w in cnc.writes], 0.0) == []
    held = cnc.writes[-1]["X"]
    assert held == pytest.approx(10.0)

    cnc.held, n = {"X": (held, True)}, len(cnc.writes)  # bridge restart: the CNC kept 10 um
    second = core_for(cnc)
    second.adopt_held()
    assert second.activate(True) is None
    drive(second, cnc, t0=100.0)
    assert cnc.writes[n]["X"] == pytest.approx(held), "the first write is what was held"
    assert unsafe_steps([w["X"] for w in cnc.writes[n:]], held) == []
    assert cnc.writes[-1]["X"] == pytest.approx(20.0)

    cnc.held, n = {"X": (-5000.0, True)}, len(cnc.writes)   # CNC restart with a wrong offset
    third = core_for(cnc)
    third.adopt_held()
    assert third.activate(True) is not None
    drive(third, cnc, t0=300.0)
    assert len(cnc.writes) == n

    cnc.held = {"X": (-5000.0, False)}                   # the operator: compensation off
    fourth = core_for(cnc)
    fourth.adopt_held()
    assert fourth.activate(True) is None
    drive(fourth, cnc, t0=400.0)
    assert unsafe_steps([w["X"] for w in cnc.writes[n:]], 0.0) == []
    assert cnc.writes[n]["X"] == 0.0 and cnc.writes[-1]["X"] == pytest.approx(20.0)


def test_the_envelope_alone_never_clamps_a_held_offset_in_one_step():
    """A caller that writes despite the refusal still only ramps at the rate limit."""
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=LIMIT, max_rate_um_per_s=RATE, max_step_s=DT))
    [a] = env.adopt_held({"X": -5000.0}, {"X": True})
    assert a.refused and env.applied["X"] == -5000.0
    values = []
    for k in range(50):
        [d] = env.step(k * DT, {"X": 20.0}, fresh=True)
        env.confirm("X", d.applied_um)
        values.append(d.applied_um)
    steps = [abs(b - a) for a, b in zip([-5000.0] + values, values)]
    assert max(steps) <= RATE * DT + 1e-9


@pytest.mark.parametrize("held_mm", [-5.0, 1e6])
def test_against_the_emulator_activation_is_refused_and_the_cnc_sees_no_write(port, held_mm):
    """The attack's case over OPC UA: X = -5 mm (and 1e9 um) held with compensation on."""
    state = EmulatorState(compensation={"X": {"SD43900": held_mm, "SD43910": 0.0, "SD43920": 0.0,
                                              "MD32750": 1}})
    emu = CncEmulatorThread(EmulatorConfig(port=port, compensation_axes=("X",), position_axes=()))
    emu.start(state)
    be = OpcUaBackend(OpcUaConfig(endpoint=emu.config.endpoint, timeout_s=1.0,
                                  node_map=default_node_map(("X",), position_axes=())))
    try:
        assert be.wait_connected(15.0), be.last_error
        core = core_for(be)
        [a] = core.adopt_held()
        assert a.held_um == pytest.approx(held_mm * 1000.0) and a.refused
        assert core.activate(True) is not None and not core.writing
        drive(core, be)
        assert emu.write_log == [], "configure and a refused activation write nothing"
        assert emu.applied_um()["X"] == pytest.approx(held_mm * 1000.0)
    finally:
        be.close()
        emu.close()


def test_counters_for_the_diagnostics():
    core = core_for(ScriptedCnc())
    cnc = core.backend
    core.adopt_held()
    assert core.activate(True) is None
    core.update(0.0, errors(E_X0C=40.0), ORIGIN, fresh=True)        # X clamped + rate, Y Z rate 0
    c = core.counters
    assert (c.writes, c.clamps, c.rate_limited, c.write_failures) == (1, 1, 1, 0)
    assert c.last_confirmed_t == 0.0 and c.last_confirmed_um == {"X": 0.0, "Y": 0.0, "Z": 0.0}
    core.update(4.0, {"E_X0C": float("nan")}, ORIGIN, fresh=True)   # refused by the transform
    assert c.refusals == 1
    cnc.answer = {"Y": lambda v: None}                                # Y not confirmed
    core.update(8.0, errors(E_X0C=40.0), ORIGIN, fresh=True)
    assert c.write_failures == 1 and c.writes == 3
    assert c.last_confirmed_t == 8.0 and c.last_confirmed_um["X"] == pytest.approx(4.0)
    assert not c.watchdog
    core.update(8.0 + 2000.0, None, ORIGIN, fresh=False)              # no fresh prediction: watchdog
    assert c.watchdog


class ReconnectingCnc(ScriptedCnc):
    """A ScriptedCnc that reconnects: ``restart(held)`` is what the OPC UA backend does when
    the CNC comes back (reads what it holds, refuses writes until that is adopted)."""

    reconnect_pending = False

    def restart(self, held):
        self.held, self.reconnect_pending = held, True

    def write_offsets(self, offsets_um):
        assert not self.reconnect_pending, "a write before the reconnection was adopted"
        return super().write_offsets(offsets_um)

    def adopt(self, adopted_um):
        self.reconnect_pending = False


def test_a_cnc_restart_is_adopted_by_the_start_up_rule(tmp_path):
    cnc, rec = ReconnectingCnc({"X": (0.0, True)}), Recorder()
    core = core_for(cnc, AuditLog(tmp_path / "audit.csv"), rec)
    core.adopt_held()
    assert core.activate(True) is None
    drive(core, cnc, n=5)                                   # 0, 5, 10, 15, 20 um
    cnc.restart({"X": (-10.0, True)})                       # back with -10 um
    n = len(cnc.writes)
    drive(core, cnc, t0=100.0, n=8)
    assert cnc.writes[n]["X"] == pytest.approx(-10.0 + RATE * DT), "from what is held, at the rate"
    assert unsafe_steps([w["X"] for w in cnc.writes[n:]], -10.0) == []
    assert cnc.writes[-1]["X"] == pytest.approx(20.0)
    cnc.restart({"X": (20.0, True)})                        # back with what was confirmed
    drive(core, cnc, t0=200.0, n=1)
    cnc.restart({"X": (-5000.0, True)})                     # back with -5 mm, compensation on
    n = len(cnc.writes)
    drive(core, cnc, t0=300.0)
    assert len(cnc.writes) == n and not core.writing and not core.active
    assert rec.kinds() == [bc.ACTIVATION_REFUSED] and rec.reports[0][1].startswith(
        "reconnect refused, not writing: after a reconnection the CNC applies X = -5000.000 um")
    assert not core.deactivate(), "refused: deactivating does not ramp the held offset either"
    assert core.activate(True) is not None, "stays inactive until configured again"
    c = core.counters
    assert (c.reconnections, c.reconnect_adoptions, c.reconnects_refused) == (3, 1, 1)
    notes = [r["note"].split(":")[0] for r in read_audit_log(tmp_path / "audit.csv")
             if r["note"].startswith("reconnect")]
    assert notes == ["reconnect|adopted-held", "reconnect|as-confirmed", "reconnect|refused",
                     "reconnect refused, not writing"]
