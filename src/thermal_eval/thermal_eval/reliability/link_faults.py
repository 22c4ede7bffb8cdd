"""CNC-link faults: the safety envelope and the OPC UA backend against the CNC emulator
while its server restarts, resets, stalls, refuses a login or a write (:func:`run_link_fault`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from asyncua import ua

from cnc_bridge.cnc_emulator import CncEmulatorThread, EmulatorConfig
from cnc_bridge.offset_backend import adopt_held_state, reconnect_pending
from cnc_bridge.opcua_backend import OpcUaBackend
from cnc_bridge.opcua_config import OpcUaConfig, default_node_map
from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
from thermal_eval.reliability.offset_safety_checks import OffsetViolation, step_violations

@dataclass
class LinkFaultResult:
    """One CNC-link fault: what the envelope and the CNC did around it."""

    fault: str
    survived: bool                 # writes confirmed again after the fault, offsets where commanded
    writes_failed: int             # writes flagged LIMIT_WRITE_FAILED during the fault
    violations: list[OffsetViolation]
    detail: str = ""


def run_link_fault(fault: str, port: int, steps_before: int = 12, steps_during: int = 4,
                   steps_after: int = 12, target_um: float = 8.0, max_rate_um_per_s: float = 0.1,
                   dt_s: float = 10.0) -> LinkFaultResult:
    """Drive SafetyEnvelope + OpcUaBackend against the CNC emulator (own thread) and inject
    ``fault`` between ``steps_before`` and ``steps_before + steps_during`` envelope steps:

    - ``server_restart``: the OPC UA server stops and starts again with its state;
    - ``server_reset``: the server restarts with its compensation reset to zero (a CNC reboot);
    - ``stalled``: the server is gone for the whole fault window (connection stalls), then back;
    - ``wrong_credentials``: the server requires a user the bridge does not log in as;
    - ``rejected_write``: the CNC refuses writes of X's offset node (made read-only on the
      server: BadNotWritable) for the fault window;
    - ``bridge_restart``: a new backend and envelope (a restarted bridge process) take over
      while the CNC holds an offset.

    The envelope's command ramps to ``target_um`` on axis X (and Y). Unsafe = any write
    that moves the CNC's applied offset by more than ``max_rate * dt`` from what it applied
    before (a restart's value included), or beyond the absolute limit.
    """

    endpoint = f"opc.tcp://127.0.0.1:{port}/thermal-comp/cnc"
    emu_cfg = EmulatorConfig(port=port, compensation_axes=("X", "Y"),
                             **({"user": "cnc", "password": "s3cret"} if fault == "wrong_credentials" else {}))
    axes = ("X", "Y")
    node_map = dict(default_node_map(axes))
    env_cfg = EnvelopeConfig(abs_limit_um=30.0, max_rate_um_per_s=max_rate_um_per_s, max_step_s=dt_s,
                             watchdog_timeout_s=1e6)

    def make_backend(**kw):
        return OpcUaBackend(OpcUaConfig(endpoint=endpoint, node_map=node_map, timeout_s=1.0,
                                        check_period_s=0.2, reconnect_min_s=0.1, reconnect_max_s=0.5, **kw),
                            inline=True)      # the client's loop in this thread, as in the cnc_bridge node

    emu = CncEmulatorThread(emu_cfg).start()
    backend = None
    failed = 0
    try:
        creds = {"user": "cnc", "password": "wrong"} if fault == "wrong_credentials" else {}
        backend = make_backend(**creds)
        backend.wait_connected(1.0 if fault == "wrong_credentials" else 10.0)
        env = SafetyEnvelope(env_cfg)
        t = 0.0

        def step(during: bool) -> None:
            nonlocal t, failed
            t += dt_s
            if reconnect_pending(backend):      # a restarted CNC: adopted as at start-up
                adopt_held_state(env, backend)
            decisions = env.step(t, {a: target_um for a in axes}, fresh=True)
            back = backend.write_offsets({d.axis: d.applied_um for d in decisions})
            for d in decisions:
                env.confirm(d.axis, back.get(d.axis))
                if back.get(d.axis) is None and during:
                    failed += 1

        for _ in range(steps_before):
            step(False)
        _begin_fault(fault, emu, node_map["X"].offset)
        if fault == "bridge_restart":
            backend.close()
            backend = make_backend()
            backend.wait_connected(10.0)
            env = SafetyEnvelope(env_cfg)
            adopt_held_state(env, backend)      # what a restarted bridge does at configure
        for _ in range(steps_during):
            step(True)
        _end_fault(fault, emu, node_map["X"].offset, backend)
        for _ in range(steps_after):
            step(False)
        return _verdict(fault, backend, emu, env, axes, failed, max_rate_um_per_s * dt_s)
    finally:
        if backend is not None:
            backend.close()
        emu.close()



def _begin_fault(fault: str, emu, x_offset_node: str) -> None:
    """What happens to the CNC's server when the fault window opens."""
    if fault in ("server_restart", "server_reset"):
        emu.restart(keep_state=fault == "server_restart")
    elif fault == "stalled":
        emu.stop()
    elif fault == "rejected_write":
        _set_writable(emu, x_offset_node, False)


def _end_fault(fault: str, emu, x_offset_node: str, backend) -> None:
    """The server back to normal when the fault window closes; the backend reconnects."""
    if fault == "stalled":
        emu.start(emu.emulator.state)
    elif fault == "rejected_write":
        _set_writable(emu, x_offset_node, True)
    if fault in ("server_restart", "server_reset", "stalled", "rejected_write"):
        backend.wait_connected(10.0)


def _verdict(fault: str, backend, emu, env, axes, failed: int, max_step_um: float) -> LinkFaultResult:
    """Did the link survive: the CNC holds what the envelope applied (or, for wrong
    credentials, nothing was written), no write broke the envelope, the fault was seen."""
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and fault != "wrong_credentials":
        if backend.connected:
            break
        backend.serve()
        time.sleep(0.05)
    applied = emu.applied_um()
    violations = []
    for a, before, after in emu.moves:       # each write against what the CNC held before it
        violations += step_violations([after], max_step_um, env.config.abs_limit_um, a, start_um=before)
    if fault == "wrong_credentials":
        survived = not backend.connected and all(abs(v) < 1e-9 for v in applied.values())
        detail = f"refused: {backend.last_error}"
    else:
        survived = backend.connected and all(abs(applied[a] - env.applied[a]) < 1e-6 for a in axes)
        detail = f"CNC holds {', '.join(f'{a}={applied[a]:.3f}' for a in axes)} um"
    if fault != "wrong_credentials" and failed == 0 and fault != "bridge_restart":
        survived = False
        detail += "; the fault was not seen (no write failed during it)"
    return LinkFaultResult(fault, bool(survived), failed, violations, detail)


def _set_writable(emu, node_id: str, writable: bool) -> None:
    """Fault injection on the emulator's own server: make ``node_id`` (not) writable."""

    async def change():
        node = emu.emulator._server.get_node(ua.NodeId.from_string(node_id))
        await node.set_writable(writable)
    emu._run(change())
