"""CNC link faults against the OPC UA emulator: the envelope holds what the CNC confirmed,
failed writes are flagged, and nothing reaches the CNC faster than the rate limit."""
from __future__ import annotations

import logging

import pytest

from thermal_eval.reliability import fault_injection as fi
@pytest.fixture(autouse=True)
def _quiet():
    for name in ("asyncua", "cnc_bridge"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


# (a plain server restart keeping its state: test/bridge/test_opcua_backend.py; bench faults)
@pytest.mark.parametrize("fault", ["server_reset", "stalled", "rejected_write"])
def test_link_fault_is_flagged_held_and_recovered_without_an_unsafe_write(fault):
    from cnc_bridge.cnc_emulator import free_tcp_port
    r = fi.run_link_fault(fault, free_tcp_port(), steps_before=6, steps_during=3, steps_after=8,
                          target_um=6.0)
    assert r.violations == [], [str(v) for v in r.violations]
    assert r.writes_failed > 0, r.detail               # the fault was seen and flagged
    assert r.survived, r.detail                        # the CNC ends where the envelope says


def test_wrong_credentials_write_nothing():
    from cnc_bridge.cnc_emulator import free_tcp_port
    r = fi.run_link_fault("wrong_credentials", free_tcp_port(), steps_before=2, steps_during=2, steps_after=2)
    assert r.survived and r.violations == []
    assert "BadUserAccessDenied" in r.detail


def test_the_write_check_sees_every_written_value():
    log = [("ns=2;s=TempComp.X.SD43900", 0.001), ("ns=2;s=TempComp.Y.SD43900", 0.5),
           ("ns=2;s=TempComp.X.MD32750", 1), ("ns=2;s=TempComp.X.SD43900", 0.0)]
    assert fi.written_offsets_um(log, "X") == [1.0, 0.0]
    assert len(fi.step_violations([1.0, 0.0, 9.0], 1.0, 30.0, "X")) == 1
