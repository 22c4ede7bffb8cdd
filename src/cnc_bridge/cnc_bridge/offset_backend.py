"""The one interface through which offsets reach a machine, and the `twin` backend.

A backend writes the envelope's offsets (axis -> um) and answers, per axis, what the
machine confirmed holding (read back), or ``None`` when the write was not confirmed. The
node never talks to a machine any other way.

* ``twin`` (:class:`TwinBackend`): no protocol. The simulated machine (the ``machine_sim``
  node) applies ``applied_offsets_um`` from the ``offsets`` topic that the bridge publishes,
  so publishing *is* the write and the read-back is the value itself.
* ``opcua`` (:class:`cnc_bridge.opcua_backend.OpcUaBackend`): an asyncua client against a
  real (or emulated) CNC.

:func:`make_backend` builds either from the bridge's parameters (asyncua loads only for opcua).
"""
from __future__ import annotations

from typing import Any, Mapping, Protocol

from thermal_comp_common.components import FIVE_AXIS_COMPONENTS


class CncBackend(Protocol):
    """What the cnc_bridge node needs from a machine connection."""

    name: str

    def write_offsets(self, offsets_um: Mapping[str, float]) -> dict[str, float | None]:
        """Write every axis' offset [um]; return axis -> read-back [um] or None (not confirmed)."""

    def axis_positions(self) -> dict[str, float]:
        """Axis positions the machine itself reports (mm / deg); empty if it reports none."""

    def held_offsets(self) -> dict[str, float]:
        """Offsets [um] the machine holds now (a restarted bridge continues from them)."""

    def close(self) -> None:
        """Release the connection."""


class TwinBackend:
    """Closes the loop into machine_sim through the ``offsets`` topic (nothing to connect)."""

    name = "twin"

    def write_offsets(self, offsets_um: Mapping[str, float]) -> dict[str, float | None]:
        return {axis: float(v) for axis, v in offsets_um.items()}

    def axis_positions(self) -> dict[str, float]:
        return {}

    def held_offsets(self) -> dict[str, float]:
        return {}

    def close(self) -> None:
        pass


def adopt_held_state(envelope, backend) -> list:
    """Start ``envelope`` from what the machine behind ``backend`` holds, before any write:
    every start-up of a bridge (a first start, a restart, a reconnection) goes through here, so the held
    offsets are adopted only within the envelope (beyond it: marked refused, never clamped;
    an axis whose compensation is off counts as 0) and the first write moves from them
    within the rate limit. Returns the
    :class:`~cnc_bridge.safety_envelope.HeldAdoption` of every axis, for the audit."""
    held = backend.held_state() if hasattr(backend, "held_state") else {}
    adopted = envelope.adopt_held({a: v for a, (v, _) in held.items()},
                                  {a: on for a, (_, on) in held.items()})
    if hasattr(backend, "adopt"):
        backend.adopt({a.axis: a.adopted_um for a in adopted})
    return adopted


def reconnect_pending(backend) -> bool:
    """``backend`` reconnected and what the machine holds now is not adopted yet: its writes
    are refused until :func:`adopt_held_state` ran again (a restarted CNC may hold anything)."""
    return bool(getattr(backend, "reconnect_pending", False))


def make_backend(p: Mapping[str, Any]):
    """The backend for the bridge parameters ``p`` (:mod:`cnc_bridge.bridge_params`); opcua:
    connected within ``connect_timeout_s`` or :class:`ConnectionError`, its client's event
    loop run in the caller's thread (call its ``serve`` between writes)."""
    if p["backend"] == "twin":
        return TwinBackend()
    # heavy: asyncua (and the credentials' YAML) only for an opcua backend
    from cnc_bridge.credentials import load_credentials
    from cnc_bridge.opcua_backend import OpcUaBackend
    from cnc_bridge.opcua_config import OpcUaConfig, default_node_map, load_node_map
    if p["node_map_file"]:
        node_map, scale = load_node_map(p["node_map_file"])
    else:
        axes = tuple(a for a in p["offset_axes"] if a)
        if p["compensation_mode"] == "kinematic" and axes == ("X", "Y", "Z"):
            axes = FIVE_AXIS_COMPONENTS   # one CNC parameter per location error
        node_map, scale = default_node_map(axes), 0.001
    creds = load_credentials(p["credentials_file"] or None)
    backend = OpcUaBackend(OpcUaConfig(
        endpoint=p["endpoint"], node_map=node_map, offset_units_per_um=scale,
        user=creds.user, password=creds.password,
        certificate=p["certificate"] or None, private_key=creds.private_key,
        server_certificate=p["server_certificate"] or None,
        server_trust=(p["server_trust"],) if p["server_trust"] else (),
        security_required=p["security_required"], timeout_s=p["request_timeout_s"]),
        inline=True)      # the client's loop runs in the caller's thread: no hop per write
    if not backend.wait_connected(p["connect_timeout_s"]):
        error = backend.last_error or "no answer"
        backend.close()
        raise ConnectionError(f"not connected to {p['endpoint']} within "
                              f"{p['connect_timeout_s']} s: {error}")
    return backend
