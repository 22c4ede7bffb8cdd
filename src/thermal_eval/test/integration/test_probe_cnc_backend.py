"""The CNC backend: the probe cycle through OPC UA against the cnc_bridge CNC emulator.

The emulator's ``ProbeMove`` method answers from thermal_twin.machine.artefact_geometry with the
compensation the emulator applies, so the whole path (client -> OPC UA method -> skip
position) is real. The compensation is written the way the bridge writes it (SD43900 in mm
plus the MD32750 enable).
"""
from __future__ import annotations

import time

import pytest

import asyncua  # noqa: E402,F401  (a hard dependency: setup.sh installs it)
from asyncua import ua  # noqa: E402
from asyncua.sync import Client  # noqa: E402

from cnc_bridge.cnc_emulator import (CncEmulatorThread, EmulatorConfig,  # noqa: E402
                                     artefact_probe, compensation_node_id, free_tcp_port)
from thermal_twin.machine.artefact_geometry import (ARTEFACT_GUIDE_BUSH, SPHERE_COMPONENTS,  # noqa: E402
                                            DEFAULT_GEOMETRY)
from probe_cycle.cnc_probe_backend import CncProbeBackend, CncProbeNodes  # noqa: E402
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine  # noqa: E402

# the emulator reads positions at 1 um: a centre from 5 quantised touches is within a
# fraction of a micrometre; eq. 5.4-5.10 then stay within these bounds (Table 5.4 column
# "theoretical resolution" is 0.25 um / 3.1 um/m)
TOL = {"um": 0.5, "um/m": 4.0}


@pytest.fixture()
def emulator():
    truth = {}
    cfg = EmulatorConfig(port=free_tcp_port(), compensation_axes=("X", "Y", "Z", "GB_X"))
    emu = CncEmulatorThread(cfg, probe_move=artefact_probe(lambda: dict(truth)))
    emu.start()
    try:
        yield emu, cfg, truth
    finally:
        emu.close()


def _write_compensation(endpoint, offsets_um):
    c = Client(endpoint)
    c.connect()
    try:
        for axis, um in offsets_um.items():
            c.get_node(compensation_node_id(axis, "SD43900")).write_value(
                ua.Variant(um / 1000.0, ua.VariantType.Double))
            c.get_node(compensation_node_id(axis, "MD32750")).write_value(
                ua.Variant(1, ua.VariantType.Int32))
    finally:
        c.disconnect()


def test_sphere_and_guide_bush_cycles_through_opc_ua(emulator):
    emu, cfg, truth = emulator
    engine = ProbeCycleEngine(DEFAULT_GEOMETRY)
    backend = CncProbeBackend(cfg.endpoint)
    try:
        truth.update({"E_Y0C": 3.0, "GB_X": 2.0})
        ref = engine.run(GoalSpec(set_reference=True), backend)
        assert ref.success, ref.message
        gb_ref = engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
        assert gb_ref.success, gb_ref.message

        truth.update({"E_X0C": 6.0, "E_Y0C": 15.0, "E_Z0T": -9.0, "E_A0C": 25.0,
                      "E_C0C": -20.0, "GB_X": 9.0})
        _write_compensation(cfg.endpoint, {"Y": 10.0, "GB_X": 4.0})
        deadline = time.monotonic() + 10.0
        while emu.applied_um().get("Y", 0.0) != pytest.approx(10.0):
            assert time.monotonic() < deadline, "compensation not applied by the emulator"
            time.sleep(0.05)
        r = engine.run(GoalSpec(), backend)
        assert r.success, r.message
        got = r.errors.as_dict()
        expected = {"E_X0C": 6.0, "E_Y0C": 15.0 - 10.0 - 3.0, "E_Z0T": -9.0, "E_R0T": 0.0,
                    "E_A0C": 25.0, "E_B0C": 0.0, "E_C0C": -20.0}
        for c, unit in zip(SPHERE_COMPONENTS, r.errors.units):
            assert got[c] == pytest.approx(expected[c], abs=TOL[unit]), c
        gb = engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
        assert gb.success, gb.message
        assert gb.errors.as_dict()["GB_X"] == pytest.approx(9.0 - 4.0 - 2.0, abs=0.6)
    finally:
        backend.close()


def test_unreachable_cnc_and_wrong_node_ids_fail_the_cycle_with_a_reason(emulator):
    emu, cfg, truth = emulator
    engine = ProbeCycleEngine(DEFAULT_GEOMETRY)
    wrong = CncProbeBackend(cfg.endpoint, CncProbeNodes(probe_method="ns=2;s=Probe.NoSuch"))
    try:
        r = engine.run(GoalSpec(set_reference=True), wrong)
        assert not r.success and r.errors is None
        assert "ns=2;s=Probe.NoSuch" in r.message and "C=0 point 1/5" in r.message
    finally:
        wrong.close()
    assert engine.references.sphere is None

    dead = CncProbeBackend(f"opc.tcp://127.0.0.1:{free_tcp_port()}/nothing", call_timeout_s=2.0)
    r = engine.run(GoalSpec(set_reference=True), dead)
    assert not r.success and "cannot connect" in r.message
    with pytest.raises(ValueError, match="probe_object"):
        CncProbeNodes(probe_object="not a node id ;;")
