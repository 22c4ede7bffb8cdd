"""The bridge's /diagnostics status carries what an operator asks of it: lifecycle state,
connection and security, last confirmed write (stamp, time, values), clamps and refusals with
counts, the watchdog; a refused reconnection is an ERROR naming it."""
from __future__ import annotations

from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.status import bridge_status
from cnc_bridge.offset_backend import TwinBackend
from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope

from test_held_beyond_envelope import ReconnectingCnc

PARAMS = {"backend": "opcua", "endpoint": "opc.tcp://cnc:4840"}
STAMPS = {"stamps_refused_ahead": 0, "stamps_refused_behind": 0, "stamps_refused_non_finite": 0,
          "last_stamp_refused": "none"}
KEYS = {"state", "lifecycle", "backend", "endpoint", "connected", "security", "reconnections",
        "connection_error", "writes", "clamps", "rate_limited", "refusals", "activations_refused",
        "reconnect_adoptions", "reconnects_refused", "write_failures", "watchdog", "watchdog_silent_s",
        "watchdog_timeout_s", "last_write_t_s", "last_write_utc", "last_write_um", *STAMPS}


def fmt(values):
    return ", ".join(f"{a}={v:.3f} um" for a, v in sorted(values.items())) or "nothing"


class Wall:
    s = 50.0

    def __call__(self):
        return self.s


def status(core, backend, lifecycle="active"):
    return bridge_status(core, backend, PARAMS, lifecycle, STAMPS, False, "", fmt)


def test_every_field_an_operator_asks_for():
    wall = Wall()
    cnc = ReconnectingCnc({"X": (0.0, True)})
    cnc.connected, cnc.connections, cnc.last_error = True, 1, ""
    core = BridgeCore(SafetyEnvelope(EnvelopeConfig(abs_limit_um=10.0, max_rate_um_per_s=0.5, max_step_s=10.0,
                                                    watchdog_timeout_s=5.0), enabled=False),
                      cnc, kinematic=True, wall=wall)
    core.adopt_held()
    core.activate(True)
    level, message, v = status(core, cnc, "unconfigured")
    assert set(v) == KEYS and v["last_write_t_s"] == "none" and v["last_write_utc"] == "none"
    for k in range(3):
        core.update(10.0 * k, {"X": 40.0}, {}, fresh=True)      # clamped at 10, rate 5 um per step
    wall.s += 2.0
    level, message, v = status(core, cnc)
    assert (level, message) == ("OK", "active: writing offsets")
    assert (v["state"], v["lifecycle"], v["connected"], v["security"]) == ("active", "active", True, "n/a (twin)")
    assert (v["writes"], v["clamps"], v["rate_limited"], v["refusals"]) == (3, 3, 2, 0)
    assert v["last_write_t_s"] == 20.0 and v["last_write_um"] == "X=10.000 um"
    assert v["last_write_utc"].endswith("+00:00") and v["reconnections"] == 0
    assert (v["watchdog"], v["watchdog_silent_s"], v["watchdog_timeout_s"]) == (False, 2.0, 5.0)
    wall.s += 10.0
    core.update(30.0, {"X": 40.0}, {}, fresh=False)
    level, message, v = status(core, cnc)
    assert level == "WARN" and "watchdog" in message and v["watchdog"] is True
    cnc.restart({"X": (-5000.0, True)})                           # the CNC came back with 5 mm
    cnc.connections = 2
    core.update(40.0, {"X": 40.0}, {}, fresh=True)
    level, message, v = status(core, cnc)
    assert level == "ERROR" and message.startswith("reconnect refused: after a reconnection the CNC applies X")
    assert (v["state"], v["reconnections"], v["reconnects_refused"]) == ("inactive", 1, 1)


def test_the_twin_and_an_unconfigured_node():
    level, message, v = bridge_status(None, None, PARAMS, "unconfigured", STAMPS, False, "", fmt)
    assert v["state"] == "unconfigured" and v["connected"] is False and "writes" not in v
    level, message, _ = bridge_status(None, None, PARAMS, "unconfigured", STAMPS, False, "no answer", fmt)
    assert (level, message) == ("ERROR", "configure failed: no answer")
    twin = TwinBackend()
    core = BridgeCore(SafetyEnvelope(EnvelopeConfig()), twin)
    _, _, v = bridge_status(core, twin, {"backend": "twin", "endpoint": ""}, "inactive", STAMPS, True, "", fmt)
    assert v["security"] == "n/a (twin)" and v["reconnections"] == "n/a" and v["connected"] is True

