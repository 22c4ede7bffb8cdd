"""The bridge's ``/diagnostics`` status from its core, backend and stamp guards (ROS-free).

What an operator asks of a running bridge, in one status: the lifecycle state and what the
write path does in it, the connection (endpoint, connected, security mode, reconnections,
the last connection error), the last confirmed write (stamp, wall time, values), the counts
of writes, clamps, rate-limited writes, refusals (commands, activations, reconnections,
stamps) and failed writes, and the watchdog (on, seconds since an acceptable prediction,
timeout). The node refreshes it once a second and on every change
(:meth:`cnc_bridge.cnc_bridge_node.CncBridgeNode._diagnose`).
"""
from __future__ import annotations

import datetime as _dt
from typing import Any, Mapping

from cnc_bridge.bridge_core import BridgeCore

OK, WARN, ERROR = "OK", "WARN", "ERROR"


def security_text(backend) -> str:
    """The security mode of ``backend``'s connection ("n/a (twin)" without a protocol)."""
    cfg = getattr(backend, "config", None)
    if cfg is None:
        return "n/a (twin)"
    return (("Basic256Sha256 Sign&Encrypt" if cfg.certificate else "None")
            + (", user" if cfg.user else "") + (", required" if cfg.security_required else ""))


def _utc(t: float | None) -> str:
    if t is None:
        return "none"
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).isoformat(timespec="milliseconds")


def bridge_status(core: BridgeCore | None, backend, params: Mapping[str, Any], lifecycle: str,
                  stamps: Mapping[str, Any], stamps_in_burst: bool, configure_error: str,
                  fmt) -> tuple[str, str, dict[str, Any]]:
    """(level, message, values) of the ``bridge`` status. ``lifecycle``: the node's lifecycle
    state label; ``stamps``: the stamp guards' values (:func:`stamp_values`); ``fmt`` formats
    axis -> value. Level: ERROR when configure failed, activation or a reconnection was
    refused, or the CNC is not connected; WARN when not writing, on watchdog or refusing stamps."""
    if core is None:
        state = "unconfigured"
    else:
        state = "active" if core.active else ("ramping to zero" if core.ramping_down else "inactive")
    connected = bool(getattr(backend, "connected", backend is not None))
    c = core.counters if core is not None else None
    if core is None and configure_error:
        level, message = ERROR, f"configure failed: {configure_error}"
    elif core is not None and core.held_refusal is not None:
        level, message = ERROR, ("reconnect refused: " if c.reconnects_refused else
                                 "activation refused: ") + core.held_refusal
    elif core is not None and not connected:
        level, message = ERROR, f"{state}: not connected ({getattr(backend, 'last_error', '')})"
    elif stamps_in_burst:
        level, message = WARN, f"{state}: refusing messages stamped off the graph's clock"
    elif state != "active" or (c is not None and c.watchdog):
        level = WARN
        message = state + (": watchdog holds the offsets" if c is not None and c.watchdog else
                           ": not following the predictions")
    else:
        level, message = OK, "active: writing offsets"
    connections = getattr(backend, "connections", None)
    values: dict[str, Any] = dict(
        state=state, lifecycle=lifecycle, backend=params["backend"], endpoint=params["endpoint"],
        connected=connected, security=security_text(backend),
        reconnections="n/a" if connections is None else max(connections - 1, 0),
        connection_error=getattr(backend, "last_error", "") or "none", **stamps)
    if c is not None:
        silent = core.silent_s()
        values.update(
            writes=c.writes, clamps=c.clamps, rate_limited=c.rate_limited,
            refusals=c.refusals, activations_refused=c.activations_refused,
            reconnect_adoptions=c.reconnect_adoptions, reconnects_refused=c.reconnects_refused,
            write_failures=c.write_failures, watchdog=c.watchdog,
            watchdog_silent_s="none" if silent is None else round(silent, 3),
            watchdog_timeout_s=core.envelope.config.watchdog_timeout_s,
            last_write_t_s="none" if c.last_confirmed_t is None else c.last_confirmed_t,
            last_write_utc=_utc(c.last_confirmed_wall), last_write_um=fmt(c.last_confirmed_um))
    return level, message, values
