"""The launcher drives managed nodes (configure, activate, deactivate) with deadlines, and the
cell file refuses restart loops without a pause and files that are not text."""
from __future__ import annotations

import io
import threading
import time

import pytest

from cnc_bridge.cnc_emulator import free_tcp_port
from thermal_comp.cell.config import CellConfigError, load_cell, parse_cell
from thermal_comp.cell.launcher import Launcher


@pytest.mark.parametrize("restart, expected", [
    ({"enabled": True, "backoff_s": 0}, r"nodes\[0\]\.restart\.backoff_s: expected seconds in \[0\.1, 3600\] "
                                        r"\(a restart loop needs a pause\), got 0"),
    ({"enabled": True, "max_restarts": 10**20}, r"nodes\[0\]\.restart\.max_restarts: expected an integer in \[0, 100\]"),
    ({"enabled": True, "max_restarts": -1}, r"max_restarts: expected an integer in \[0, 100\], got -1"),
])
def test_restart_loops_without_pause_or_bound_are_refused(restart, expected):
    with pytest.raises(CellConfigError, match=expected):
        parse_cell({"cell": "x", "nodes": [{"name": "a", "module": "m", "restart": restart}]}, resolve=False)
    # a disabled policy may keep a zero back-off (it never restarts)
    parse_cell({"cell": "x", "nodes": [{"name": "a", "module": "m",
                                        "restart": {"enabled": False, "backoff_s": 0}}]}, resolve=False)


@pytest.mark.parametrize("data, expected", [
    (b"cell: x\nnodes: [{name: a, module: m}]\n# \xe9t\xe9\n", r"not a UTF-8 text file \(byte 0xe9 at offset"),
    (b"\x00\x01\x02binary", r"a binary file \(NUL bytes\)"),
])
def test_a_file_that_is_not_text_is_one_line(tmp_path, data, expected):
    f = tmp_path / "cell.yaml"
    f.write_bytes(data)
    with pytest.raises(CellConfigError, match=expected) as info:
        load_cell(f, resolve=False)
    assert "\n" not in str(info.value) and str(f) in str(info.value)


def test_lifecycle_is_detected_from_the_node_module_or_set_in_the_cell():
    cell = parse_cell({"cell": "x", "nodes": [
        {"name": "bridge", "module": "cnc_bridge.cnc_bridge_node"},
        {"name": "twin", "module": "thermal_twin.machine_sim_node"},
        {"name": "off", "module": "cnc_bridge.cnc_bridge_node", "lifecycle": False}]})
    assert [n.lifecycle for n in cell.nodes] == [True, False, False]
    with pytest.raises(CellConfigError, match=r"nodes\[0\]\.lifecycle_timeout_s"):
        parse_cell({"cell": "x", "nodes": [{"name": "a", "module": "m", "lifecycle_timeout_s": 0}]},
                   resolve=False)


def _bridge_cell(name: str, domain_id: int, **params) -> dict:
    return {"cell": name, "domain_id": domain_id,
            "nodes": [{"name": "bridge", "module": "cnc_bridge.cnc_bridge_node",
                       "lifecycle_timeout_s": 20, "parameters": params,
                       "restart": {"enabled": True, "max_restarts": 3, "backoff_s": 0.5}}]}


def _wait(lines: list[str], text: str, timeout_s: float) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        hit = next((ln for ln in list(lines) if text in ln), None)
        if hit:
            return hit
        time.sleep(0.05)
    raise AssertionError(f"never saw {text!r}:\n" + "\n".join(lines[-30:]))


@pytest.mark.slow
@pytest.mark.ros
def test_launcher_configures_activates_and_deactivates_a_managed_bridge(tmp_path, ros_domain_id):
    lines: list[str] = []
    cell = parse_cell(_bridge_cell("lc_ok", ros_domain_id, backend="twin"))
    launcher = Launcher([cell], run_dir=tmp_path, output=io.StringIO(),
                        on_line=lambda label, line: lines.append(f"[{label}] {line}"))
    launcher.start()
    try:
        _wait(lines, "lc_ok/bridge: configured and active", 60)
        _wait(lines, "active: writing offsets", 10)
    finally:
        launcher.request_stop()
        launcher.stop()
    assert any("lc_ok/bridge: deactivated" in ln for ln in lines)
    assert any("deactivate: compensation off" in ln for ln in lines)
    assert launcher.lifecycle_failures == []


@pytest.mark.slow
@pytest.mark.ros
def test_a_failed_configure_is_one_error_naming_the_node_and_no_restart(tmp_path, ros_domain_id):
    lines: list[str] = []
    cell = parse_cell(_bridge_cell("lc_bad", ros_domain_id, backend="opcua", connect_timeout_s=1.0,
                                   endpoint=f"opc.tcp://127.0.0.1:{free_tcp_port()}/nobody"))
    launcher = Launcher([cell], run_dir=tmp_path, output=io.StringIO(),
                        on_line=lambda label, line: lines.append(f"[{label}] {line}"))
    code: list[int] = []
    runner = threading.Thread(target=lambda: code.append(launcher.run(poll_s=0.1)), daemon=True)
    runner.start()
    runner.join(120)
    if runner.is_alive():
        launcher.request_stop()
        runner.join(30)
        raise AssertionError("the launcher did not end after a failed configure:\n" + "\n".join(lines[-30:]))
    assert code == [1]
    error = _wait(lines, "ERROR lc_bad/bridge:", 1)
    assert "transition 'configure' failed" in error and "no restart" in error
    assert any("configure failed, nothing written" in ln for ln in lines)
    mp = launcher.processes[0]
    assert mp.restarts == 0 and mp.gave_up and launcher.lifecycle_failures


@pytest.mark.slow
@pytest.mark.ros
def test_a_node_marked_lifecycle_without_the_services_fails_within_the_deadline(tmp_path, ros_domain_id):
    from ros_helpers import PROCS
    lines: list[str] = []
    cell = parse_cell({"cell": "lc_plain", "domain_id": ros_domain_id, "env": {"PYTHONPATH": str(PROCS)},
                       "nodes": [{"name": "talker", "module": "temperature_talker", "lifecycle": True,
                                  "lifecycle_timeout_s": 3, "parameters": {"period_s": 0.5}}]},
                      resolve=False)
    launcher = Launcher([cell], run_dir=tmp_path, output=io.StringIO(),
                        on_line=lambda label, line: lines.append(f"[{label}] {line}"))
    t0 = time.monotonic()
    code = launcher.run(poll_s=0.1)
    assert code == 1 and time.monotonic() - t0 < 60
    error = _wait(lines, "ERROR lc_plain/talker:", 1)
    assert "no lifecycle service /lc_plain/talker/change_state within 3 s" in error
