"""The emulator's start-up deadline scales with the machine's load, and a missed one says so."""
from __future__ import annotations

import pytest

from cnc_bridge.cnc_emulator import CncEmulatorThread, EmulatorConfig, free_tcp_port
from cnc_bridge.cnc_emulator import thread as emulator_thread


@pytest.mark.parametrize("load, cores, expected", [(0.5, 4, 20.0), (4.0, 4, 20.0), (12.0, 4, 60.0)])
def test_startup_deadline_scales_with_load(monkeypatch, load, cores, expected):
    monkeypatch.setattr(emulator_thread.os, "getloadavg", lambda: (load, load, load))
    monkeypatch.setattr(emulator_thread.os, "cpu_count", lambda: cores)
    assert emulator_thread.startup_deadline_s() == pytest.approx(expected)


def test_a_missed_startup_deadline_names_the_emulator_and_the_deadline(monkeypatch):
    monkeypatch.setattr(emulator_thread, "startup_deadline_s", lambda: 1e-3)
    emu = CncEmulatorThread(EmulatorConfig(port=free_tcp_port()))
    try:
        with pytest.raises(TimeoutError, match=r"CNC emulator on opc\.tcp://127\.0\.0\.1:\d+/.*: not listening "
                                               r"within 0 s \(20 s scaled by the machine's load\)"):
            emu.start()
    finally:
        emu._io.stop()
