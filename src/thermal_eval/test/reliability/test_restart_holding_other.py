"""A CNC that restarts holding something else while the bridge is connected, and a bridge that
restarts against one: never a write beyond the rate limit from what the CNC applies, never a
value beyond the absolute limit (the project's unsafe write: ``step_violations``, each write
against what the CNC applied just before it). The bridge adopts what is held and ramps from
it, or, held beyond the envelope with compensation on, refuses and stays inactive; the audit
says which. Black box: the bridge's write path against the in-process CNC emulator."""
from __future__ import annotations

import logging

import pytest

from cnc_bridge.cnc_emulator import free_tcp_port
from thermal_eval.reliability.bridge_attacks import LIMIT_UM, RATE_UM_PER_S, DT_S, restart_case

pytestmark = [pytest.mark.slow]      # 12 emulator start-ups and restarts: about 2 minutes


@pytest.fixture(autouse=True)
def _quiet():
    for name in ("asyncua", "cnc_bridge", "cnc_emulator"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


@pytest.mark.parametrize("restart", ["cnc", "bridge"])
@pytest.mark.parametrize("held_um, enabled, adopted", [(-10.0, 1, -10.0), (0.0, 1, 0.0), (5000.0, 0, 0.0),
                                                       (25.0, 1, 25.0)])
def test_a_different_held_value_is_adopted_and_ramped_from(restart, held_um, enabled, adopted):
    r = restart_case(free_tcp_port(), held_um, enabled, restart)
    assert r["unsafe"] == 0
    assert r["refused"] is None and r["writing"]
    assert r["applied_um"] == pytest.approx(20.0)                 # back where the model asks
    [note] = r["notes"][-1:]
    if restart == "cnc":
        kind = "as-confirmed" if adopted == 20.0 else "adopted-held"
        assert note.startswith(f"reconnect|{kind}: X: held {held_um:.3f} um")
        assert f"adopted {adopted:.3f} um" in note and note.endswith("last confirmed 20.000 um")
        assert r["reconnect_adoptions"] == 1
    else:
        assert note.startswith(f"start-up: X: held {held_um:.3f} um") and f"adopted {adopted:.3f} um" in note
    # the ramp from the adopted value takes as many steps as the rate limit demands, not one
    assert r["moves_after"] >= abs(20.0 - adopted) / (RATE_UM_PER_S * DT_S)


@pytest.mark.parametrize("restart", ["cnc", "bridge"])
@pytest.mark.parametrize("held_um", [-5000.0, 1e9])
def test_held_beyond_the_envelope_with_compensation_on_is_refused_and_nothing_is_written(restart, held_um):
    r = restart_case(free_tcp_port(), held_um, 1, restart)
    assert r["unsafe"] == 0 and r["moves_after"] == 0
    assert not r["writing"] and r["applied_um"] == pytest.approx(held_um)
    line = r["refused"]
    assert line is not None and "\n" not in line and f"beyond the absolute limit {LIMIT_UM:g} um" in line
    assert "configure again" in line
    if restart == "cnc":
        assert r["notes"][0].startswith("reconnect|refused: X: held")
        assert r["notes"][1].startswith("reconnect refused, not writing: after a reconnection the CNC applies X")
    else:
        assert r["notes"][-1].startswith("activate refused: the CNC applies X")


def test_the_row_sees_the_old_re_apply_as_an_unsafe_write(monkeypatch):
    """The re-apply of the last confirmed offset over what a restarted CNC holds (the bridge's
    behaviour before a reconnection was a start-up) is one write of 30 um where 5 um are allowed."""
    from cnc_bridge.bridge_core import BridgeCore
    from thermal_eval.reliability import bridge_attacks

    def re_apply_last_confirmed(core):
        if core.backend.reconnect_pending:
            core.backend.adopt(core.envelope.applied)
        return []
    monkeypatch.setattr(BridgeCore, "readopt_after_reconnect", re_apply_last_confirmed)
    row = bridge_attacks._restart_row(free_tcp_port(), "cnc", -10.0, 1, "-10 um")
    assert not row["survived"] and row["unsafe_writes"] == 1
