"""Rows of ``thermal-comp bench faults`` for attacks and clumsy operations on the
CNC bridge, its OPC UA link and the launcher's cell files.

Each case runs the real pieces in-process (CNC emulator over loopback OPC UA, the OPC UA
backend, the safety envelope, the cell-file parser) or the bridge node as a process where
the case is about the node itself. "unsafe writes" counts values the CNC accepted that are
non-finite, beyond the absolute limit in force, or faster than the rate limit from what the
CNC applied before (at start-up: what it held, if its compensation was on).
"""
from __future__ import annotations

import asyncio
import logging
import math
import pathlib
import os
import subprocess
import sys
import tempfile
import time

from asyncua import Client, ua

from cnc_bridge.audit_log import AuditLog, read_audit_log
from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.certificates import make_certificate
from cnc_bridge.cnc_emulator import (CncEmulatorThread, EmulatorConfig, EmulatorState, compensation_node_id,
                                      free_tcp_port)
from cnc_bridge.opcua_backend import OpcUaBackend
from cnc_bridge.opcua_config import OpcUaConfig, default_node_map
from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
from thermal_comp.cell.config import CellConfigError, parse_cell

from thermal_eval.reliability.fault_injection import (offset_violations, step_violations,
                                                     written_offsets_um)
from thermal_eval.reliability.fault_rows import guarded

LIMIT_UM, RATE_UM_PER_S, DT_S = 30.0, 0.5, 10.0


def _row(fault: str, survived: bool, unsafe: int, detail: str) -> dict:
    return {"area": "bridge", "fault": fault, "injected": 1, "survived": bool(survived),
            "data_lost": 0, "unsafe_writes": int(unsafe), "detail": detail[:90]}


def _emulator(port: int, held_mm: float, enabled: int, **kw):
    state = EmulatorState(compensation={"X": {"SD43900": held_mm, "SD43910": 0.0, "SD43920": 0.0,
                                              "MD32750": enabled}})
    emu = CncEmulatorThread(EmulatorConfig(port=port, compensation_axes=("X",), position_axes=(), **kw))
    emu.start(state)
    return emu


def _start_up(port: int, held_mm: float, enabled: int, limit_after: float | None = None):
    """Configure (connect, read, adopt), then 20 activated steps towards +20 um (the limit
    lowered to ``limit_after`` at step 5). Returns (adoption, what the CNC applied per step,
    unsafe writes, CNC writes before the first step)."""
    emu = _emulator(port, held_mm, enabled)
    be = OpcUaBackend(OpcUaConfig(endpoint=emu.config.endpoint, timeout_s=1.0,
                                  node_map=default_node_map(("X",), position_axes=())))
    try:
        if not be.wait_connected(10.0):
            raise RuntimeError(f"no connection: {be.last_error}")
        written_before = len(emu.write_log)
        env = SafetyEnvelope(EnvelopeConfig(LIMIT_UM, max_rate_um_per_s=RATE_UM_PER_S, max_step_s=DT_S))
        held = be.held_state()
        [adoption] = env.adopt_held({a: v for a, (v, _) in held.items()},
                                    {a: on for a, (_, on) in held.items()})
        be.adopt({adoption.axis: adoption.adopted_um})
        env.set_enabled(True)
        times, applied, limits = [], [], []
        for k in range(20):
            if limit_after is not None and k == 5:
                env.reconfigure(EnvelopeConfig(limit_after, max_rate_um_per_s=RATE_UM_PER_S,
                                               max_step_s=DT_S))
            d = {x.axis: x for x in env.step(k * DT_S, {"X": 20.0}, fresh=True)}
            back = be.write_offsets({"X": d["X"].applied_um})
            env.confirm("X", back["X"])
            times.append(k * DT_S)
            applied.append(emu.applied_um()["X"])
            limits.append(env.config.abs_limit_um)
        bad = offset_violations(times, {"X": applied}, RATE_UM_PER_S, LIMIT_UM, DT_S,
                                start_um={"X": adoption.adopted_um})
        # beyond a limit lowered at run time, a value may only move back towards it
        away = sum(1 for prev, v, lim in zip(applied, applied[1:], limits[1:])
                   if abs(v) > lim and abs(v) > abs(prev) + 1e-9)
        return adoption, applied, len(bad) + away, written_before
    finally:
        be.close()
        emu.close()


def _activation_against_held(port: int, held_mm: float) -> tuple[str | None, int, int]:
    """The bridge's own write path (configure: adopt; activate; 20 predictions as the node
    drives them) against a CNC holding ``held_mm`` with compensation on. Returns (the
    refusal line or None, CNC offset writes, unsafe writes from the held value)."""
    emu = _emulator(port, held_mm, 1)
    be = OpcUaBackend(OpcUaConfig(endpoint=emu.config.endpoint, timeout_s=1.0,
                                  node_map=default_node_map(("X",), position_axes=())))
    try:
        if not be.wait_connected(10.0):
            raise RuntimeError(f"no connection: {be.last_error}")
        env = SafetyEnvelope(EnvelopeConfig(LIMIT_UM, max_rate_um_per_s=RATE_UM_PER_S, max_step_s=DT_S),
                             enabled=False)
        core = BridgeCore(env, be, kinematic=True)   # kinematic: the command is the axis value
        core.adopt_held()
        refused = core.activate(True)
        for k in range(20):
            if core.writing:
                core.update(k * DT_S, {"X": 20.0}, {}, fresh=True)
        written = written_offsets_um(emu.write_log, "X")
        bad = step_violations(written, RATE_UM_PER_S * DT_S, LIMIT_UM, "X", start_um=held_mm * 1000.0)
        return refused, len(written), len(bad)
    finally:
        be.close()
        emu.close()


def _backend(emu) -> OpcUaBackend:
    """An X-only backend as the node runs it (its loop inline), quick to notice a lost session."""
    return OpcUaBackend(OpcUaConfig(endpoint=emu.config.endpoint, timeout_s=1.0, check_period_s=0.2,
                                    reconnect_min_s=0.1, reconnect_max_s=0.3,
                                    node_map=default_node_map(("X",), position_axes=())), inline=True)


def _serve_until(condition, be: OpcUaBackend, timeout_s: float, what: str) -> None:
    """Serve the backend's inline loop (what the node's timer does) until ``condition()``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not within {timeout_s:g} s ({be.last_error})")
        be.serve()
        time.sleep(0.01)


def restart_case(port: int, held_um: float, enabled: int, restart: str = "cnc",
                 steps_before: int = 6, steps_after: int = 12) -> dict:
    """The bridge's write path (:class:`BridgeCore`, kinematic: the command is X itself) ramps
    X towards +20 um, then ``restart`` happens: ``"cnc"``, the CNC restarts holding ``held_um``
    (compensation ``enabled``) while the bridge is connected; ``"bridge"``, the bridge stops,
    the CNC comes back holding it, a new bridge configures and activates. The bridge keeps
    driving. Returns the audit notes of the restart, the refusal line (or None), the CNC's
    applied X at the end, how many writes moved X after the restart and the unsafe ones among
    every write (a step beyond one update's rate allowance from what the CNC applied before
    it, restart included, or beyond the absolute limit)."""
    emu = _emulator(port, 0.0, 1)
    held = EmulatorState(compensation={"X": {"SD43900": held_um / 1000.0, "SD43910": 0.0,
                                             "SD43920": 0.0, "MD32750": enabled}})
    cores: list[BridgeCore] = []
    with tempfile.TemporaryDirectory(prefix="bench_restart_") as d:
        audit = AuditLog(pathlib.Path(d) / "audit.csv")
        try:
            core = _active_core(_backend(emu), audit)
            cores.append(core)
            for k in range(steps_before):
                core.update(k * DT_S, {"X": 20.0}, {}, fresh=True)
            moved_before = len(emu.moves)
            if restart == "cnc":
                emu.restart(state=held)
                _serve_until(lambda: core.backend.connected and core.backend.connections == 2,
                             core.backend, 30.0, "reconnection")
            else:
                core.backend.close()
                emu.restart(state=held)
                core = _active_core(_backend(emu), audit)
                cores.append(core)
            for k in range(steps_before, steps_before + steps_after):
                if core.writing:
                    core.update(k * DT_S, {"X": 20.0}, {}, fresh=True)
            unsafe = sum(len(step_violations([after], RATE_UM_PER_S * DT_S, LIMIT_UM, a, start_um=before))
                         for a, before, after in emu.moves)
            notes = [r["note"] for r in read_audit_log(audit.path)
                     if r["note"].startswith(("reconnect", "start-up: X", "activate refused"))]
            return {"notes": notes[1:], "refused": core.held_refusal, "writing": core.writing,
                    "applied_um": emu.applied_um()["X"], "moves_after": len(emu.moves) - moved_before,
                    "unsafe": unsafe, "reconnect_adoptions": core.counters.reconnect_adoptions}
        finally:
            for c in cores:
                c.backend.close()
            audit.close()
            emu.close()


def _active_core(be: OpcUaBackend, audit: AuditLog) -> BridgeCore:
    """Configure (connect, read, adopt) and activate, as the node does."""
    if not be.wait_connected(10.0):
        raise RuntimeError(f"no connection: {be.last_error}")
    env = SafetyEnvelope(EnvelopeConfig(LIMIT_UM, max_rate_um_per_s=RATE_UM_PER_S, max_step_s=DT_S),
                         enabled=False)
    core = BridgeCore(env, be, audit, kinematic=True)
    core.adopt_held()
    core.activate(True)
    return core


def _restart_row(port: int, restart: str, held_um: float, enabled: int, what: str) -> dict:
    r = restart_case(port, held_um, enabled, restart)
    beyond = enabled and abs(held_um) > LIMIT_UM
    ok = r["unsafe"] == 0 and ((r["refused"] is not None and not r["writing"] and r["moves_after"] == 0)
                               if beyond else (r["refused"] is None and abs(r["applied_um"] - 20.0) < 1e-6))
    head = "refused, not writing" if r["refused"] else f"ramped back to {r['applied_um']:g} um"
    return _row(f"{restart} restart holding {what}", ok, r["unsafe"],
                f"{r['moves_after']} writes after it; {head}; audit: " + ", ".join(
                    n.split(":")[0].split(",")[0] for n in r["notes"]))


def _values_refused(port: int) -> tuple[int, int]:
    emu = CncEmulatorThread(EmulatorConfig(port=port)).start()

    async def attack():
        refused = 0
        async with Client(emu.config.endpoint) as c:
            node = c.get_node(compensation_node_id("X", "SD43900"))
            for v in (math.nan, math.inf, -math.inf, 1e9):
                try:
                    await node.write_value(ua.DataValue(ua.Variant(v, ua.VariantType.Double)))
                except ua.UaStatusCodeError as exc:
                    refused += "BadOutOfRange" in str(exc)
        return refused
    try:
        refused = asyncio.run(attack())
        accepted = sum(1 for _, v in emu.write_log if not (math.isfinite(v) and abs(v) <= 1.0))
        return refused, accepted
    finally:
        emu.close()


def _unknown_certificate(port: int) -> tuple[bool, int, str]:
    with tempfile.TemporaryDirectory(prefix="bench_bridge_attack_") as d:
        d = pathlib.Path(d)
        srv = make_certificate(d, "cnc", "urn:thermal-comp:cnc-emulator:server", server=True)
        ok = make_certificate(d, "bridge", "urn:thermal-comp:cnc-bridge", server=False)
        bad = make_certificate(d, "stranger", "urn:thermal-comp:cnc-bridge", server=False)
        emu = CncEmulatorThread(EmulatorConfig(port=port, certificate=srv[0], private_key=srv[1],
                                               security="required", user="cnc", password="pw",
                                               client_trust=(ok[0],))).start()
        be = OpcUaBackend(OpcUaConfig(endpoint=emu.config.endpoint, user="cnc", password="pw",
                                      certificate=bad[0], private_key=bad[1], security_required=True,
                                      server_trust=(srv[0],), reconnect_max_s=0.3))
        try:
            deadline = time.monotonic() + 20.0
            while "BadCertificateUntrusted" not in be.last_error and time.monotonic() < deadline:
                time.sleep(0.05)
            be.write_offsets({"X": 1.0})
            return "BadCertificateUntrusted" in be.last_error and not be.connected, len(emu.write_log), \
                be.last_error
        finally:
            be.close()
            emu.close()


def _wrong_passwords(port: int, n: int = 20) -> tuple[int, int, float]:
    emu = CncEmulatorThread(EmulatorConfig(port=port, user="cnc", password="s3cret")).start()

    async def attempts():
        got_in = 0
        for _ in range(n):
            c = Client(emu.config.endpoint, timeout=2)
            c.set_user("cnc")
            c.set_password("wrong")
            try:
                await c.connect()
                got_in += 1
                await c.disconnect()
            except Exception:
                pass
        return got_in
    try:
        t0 = time.perf_counter()
        got_in = asyncio.run(attempts())
        return got_in, emu.emulator.gate.backoff.refused_in_backoff, time.perf_counter() - t0
    finally:
        emu.close()


def _password_parameter() -> tuple[bool, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 50),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    done = subprocess.run([sys.executable, "-m", "cnc_bridge.cnc_bridge_node", "--ros-args", "-p",
                           "backend:=opcua", "-p", "password:=s3cret"], env=env, capture_output=True,
                          text=True, timeout=120)
    out = (done.stdout + done.stderr).strip().splitlines()
    line = next((ln for ln in out if "password" in ln), out[-1] if out else "")
    return done.returncode == 2 and "s3cret" not in done.stdout + done.stderr, line


def _restart_loops() -> tuple[int, str]:
    refused, last = 0, ""
    for restart in ({"enabled": True, "backoff_s": 0}, {"enabled": True, "max_restarts": 10 ** 20}):
        try:
            parse_cell({"cell": "x", "nodes": [{"name": "a", "module": "m", "restart": restart}]},
                       resolve=False)
        except CellConfigError as exc:
            refused, last = refused + 1, str(exc)
    return refused, last


def rows() -> list[dict]:
    """The bridge/launcher rows of the fault table (about 1 minute)."""
    for name in ("asyncua", "cnc_bridge", "cnc_emulator"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    out = []
    a, applied, unsafe, before = _start_up(free_tcp_port(), -5.0, 0)
    out.append(_row("start-up: -5 mm held, compensation off", unsafe == 0 and before == 0
                    and a.adopted_um == 0.0 and abs(applied[1]) <= RATE_UM_PER_S * DT_S, unsafe,
                    f"adopted {a.adopted_um:g} um; first writes {applied[0]:g}, {applied[1]:g} um"))
    for held_mm, what in ((-5.0, "-5 mm"), (1e6, "1e9 um")):
        refused, writes, unsafe = _activation_against_held(free_tcp_port(), held_mm)
        out.append(_row(f"activation: {what} held, compensation on", refused is not None and writes == 0
                        and unsafe == 0, unsafe, f"{writes} writes; " + (refused or "activated")))
    a, applied, unsafe, _ = _start_up(free_tcp_port(), 0.0, 0, limit_after=1.0)
    out.append(_row("abs_limit_um 30 -> 1 at run time", unsafe == 0 and abs(applied[-1]) <= 1.0 + 1e-9,
                    unsafe, f"20 um asked; applied {applied[4]:g} before, {applied[-1]:g} um at the end"))
    for restart, held_um, enabled, what in (("cnc", -10.0, 1, "-10 um"), ("cnc", -5000.0, 1, "-5 mm"),
                                            ("cnc", 5000.0, 0, "5 mm, compensation off"),
                                            ("bridge", -5000.0, 1, "-5 mm")):
        out += guarded("bridge", f"{restart} restart holding {what}",
                       lambda a=(restart, held_um, enabled, what): _restart_row(free_tcp_port(), *a))
    refused, accepted = _values_refused(free_tcp_port())
    out.append(_row("NaN/inf/-inf/1e9 mm written to the CNC", refused == 4 and accepted == 0, accepted,
                    f"{refused}/4 refused with BadOutOfRange"))
    ok, writes, error = _unknown_certificate(free_tcp_port())
    out.append(_row("unknown client certificate", ok and writes == 0, writes, error))
    got_in, held_back, secs = _wrong_passwords(free_tcp_port())
    out.append(_row("20 wrong passwords", got_in == 0 and held_back > 0, 0,
                    f"{held_back} refused within the back-off (even a right password); {secs:.2f} s"))
    ok, line = _password_parameter()
    out.append(_row("password as a ROS parameter", ok, 0, line))
    refused, last = _restart_loops()
    out.append(_row("restart loop: 0 s back-off / 1e20 restarts", refused == 2, 0,
                    f"{refused}/2 refused: {last.split(': ', 1)[-1]}"))
    return out
