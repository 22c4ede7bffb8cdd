"""The cnc_bridge node on /diagnostics, and its refused activation against a held 5 mm."""
from __future__ import annotations

import logging

import pytest

from cnc_bridge.audit_log import read_audit_log
from cnc_bridge.cnc_emulator import ENDPOINT_PATH, CncEmulatorThread, EmulatorConfig, free_tcp_port

from test_cnc_bridge_node import Cell, spawn_bridge, stop

logging.getLogger("asyncua").setLevel(logging.ERROR)
pytestmark = [pytest.mark.slow, pytest.mark.ros]


class DiagnosticsSeen:
    """The last ``cnc_bridge: bridge`` status received on /diagnostics."""

    def __init__(self, cell: Cell):
        from diagnostic_msgs.msg import DiagnosticArray

        from thermal_comp_common.runtime.diagnostics import DIAGNOSTICS_QOS, TOPIC_DIAGNOSTICS
        self.last = None
        self.sub = cell.node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self._on,
                                                 DIAGNOSTICS_QOS)

    def _on(self, msg) -> None:
        for s in msg.status:
            if s.name == "cnc_bridge: bridge":
                self.last = s

    def values(self) -> dict[str, str]:
        return {} if self.last is None else {kv.key: kv.value for kv in self.last.values}


def test_diagnostics_carry_state_connection_last_write_and_counts(ros_domain_id):
    proc = spawn_bridge("/bridge_diag", "backend:=twin", "lockstep:=true", "abs_limit_um:=15.0",
                        "max_rate_um_per_s:=0.5", "max_step_s:=10.0")
    cell = Cell("/bridge_diag")
    diag = DiagnosticsSeen(cell)
    try:
        cell.wait_matched()
        for k in range(4):
            t = 100.0 + 10.0 * k
            cell.state(t)
            cell.predict(t, E_Z0T=20.0)
            cell.answer_for(t)
        cell.spin_until(lambda: diag.values().get("writes") == "4", 15, "4 writes on /diagnostics")
        v, s = diag.values(), diag.last
        assert s.level == b"\x00" and s.message == "active: writing offsets"
        assert s.hardware_id == "machine_sim (twin backend)"
        assert (v["state"], v["backend"], v["connected"]) == ("active", "twin", "True")
        assert v["security"] == "n/a (twin)"
        assert v["last_write_t_s"] == "130.0" and "Z=15.000 um" in v["last_write_um"]
        # 0, 5, 10, 15 um on Z: clamped at 15 um every time, rate-limited three times
        assert (v["clamps"], v["rate_limited"], v["refusals"]) == ("4", "3", "0")
        assert (v["write_failures"], v["activations_refused"], v["watchdog"]) == ("0", "0", "False")
        assert (v["lifecycle"], v["reconnections"], v["reconnects_refused"]) == ("active", "n/a", "0")
        assert v["last_write_utc"].endswith("+00:00") and v["watchdog_timeout_s"] == "900.0"
    finally:
        cell.close()
        stop(proc)


def test_activation_against_5mm_held_with_compensation_on_is_refused(tmp_path, ros_domain_id):
    """The attack's start-up: X = -5 mm held, compensation on. Activate fails with one line,
    the node stays inactive, the CNC sees no write, the audit and /diagnostics say why."""
    from cnc_bridge.cnc_emulator import EmulatorState
    port = free_tcp_port()
    state = EmulatorState(compensation={"X": {"SD43900": -5.0, "SD43910": 0.0, "SD43920": 0.0,
                                              "MD32750": 1}})
    emu = CncEmulatorThread(EmulatorConfig(port=port, offset_limit_mm=10.0))
    emu.start(state)
    audit = tmp_path / "audit.csv"
    proc = spawn_bridge("/bridge_held", "backend:=opcua",
                        f"endpoint:=opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}", "lockstep:=true",
                        "max_rate_um_per_s:=0.5", "abs_limit_um:=30.0", f"audit_log_path:={audit}",
                        autostart=False)
    cell = Cell("/bridge_held")
    diag = DiagnosticsSeen(cell)
    node = "/bridge_held/cnc_bridge"
    try:
        assert cell.transition(node, "configure")
        assert not cell.transition(node, "activate"), "activation is refused"
        cell.wait_matched()
        for t in (0.0, 10.0):                 # still answered in lock-step, never written
            cell.state(t, X=0.0, Y=0.0, Z=0.0)
            cell.predict(t, E_X0C=20.0)
            cell.spin_until(lambda: len(cell.syncs) >= (1 if t == 0.0 else 2), 15, "SimSync")
        assert emu.write_log == [] and cell.offsets == []
        cell.spin_until(lambda: diag.values().get("activations_refused") == "1", 15, "the refusal")
        s, v = diag.last, diag.values()
        assert s.level == b"\x02" and s.message.startswith("activation refused: the CNC applies X = "
                                                           "-5000.000 um, beyond the absolute limit 30 um")
        assert (v["state"], v["connected"], v["security"], v["writes"]) == ("inactive", "True", "None", "0")
        notes = [r["note"] for r in read_audit_log(audit) if r["note"]]
        assert any(n.startswith("activate refused: the CNC applies X = -5000.000 um") for n in notes)
        assert cell.transition(node, "activate") is False          # until the operator acts
        assert emu.write_log == []
    finally:
        cell.close()
        out = stop(proc)
        emu.close()
    refused = [ln for ln in out.splitlines() if "activate refused" in ln]
    assert len(refused) == 2 and "ERROR" in refused[0]            # one line per attempt
