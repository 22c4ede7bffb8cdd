"""CNC probing backend: runs each probing move on a CNC through OPC UA (one call of a
G31-like ``ProbeMove`` method) and reads the skip position, so the same action server serves
a real machine. Method signature, node ids and failure handling: README.md ("CNC backend").
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from asyncua import ua
from asyncua.sync import Client

from probe_cycle.cycle_plan import TouchMove
from probe_cycle.probe_backend import ProbeBackend, ProbeBackendError, TouchReply

log = logging.getLogger("probe_cycle.cnc")


@dataclass(frozen=True)
class CncProbeNodes:
    """OPC UA node ids of the CNC's probing interface."""

    probe_object: str = "ns=2;s=Probe"
    probe_method: str = "ns=2;s=Probe.ProbeMove"

    def __post_init__(self):
        for name in ("probe_object", "probe_method"):
            value = getattr(self, name)
            try:
                ua.NodeId.from_string(value)
            except Exception:
                raise ValueError(f"{name}: {value!r} is not an OPC UA node id "
                                 f"(e.g. 'ns=2;s=Probe')") from None


class CncProbeBackend(ProbeBackend):
    name = "cnc"

    def __init__(self, endpoint: str, nodes: CncProbeNodes = CncProbeNodes(),
                 user: str | None = None, password: str | None = None,
                 call_timeout_s: float = 60.0, clock: Callable[[], float] = time.time):
        if not endpoint.startswith("opc.tcp://"):
            raise ValueError(f"endpoint: {endpoint!r} is not an opc.tcp:// URL")
        if (user is None) != (password is None):
            raise ValueError("user and password must be given together")
        if not call_timeout_s > 0:
            raise ValueError(f"call_timeout_s: must be > 0, got {call_timeout_s!r}")
        self.endpoint = endpoint
        self.nodes = nodes
        self.user, self.password = user, password
        self.call_timeout_s = float(call_timeout_s)
        self.clock = clock
        self._client: Client | None = None
        self._stopped = False

    def _connect(self) -> Client:
        if self._client is not None:
            return self._client
        client = Client(self.endpoint, timeout=self.call_timeout_s,
                        sync_wrapper_timeout=self.call_timeout_s + 5.0)
        if self.user is not None:
            client.set_user(self.user)
            client.set_password(self.password)
        try:
            client.connect()
        except Exception as exc:
            try:
                client.tloop.stop()
            except Exception:
                pass
            raise ProbeBackendError(f"cannot connect to {self.endpoint}: "
                                    f"{exc.__class__.__name__}: {exc}") from exc
        self._client = client
        return client

    def stop(self) -> None:
        """Refuse further moves and drop the connection, which ends a call in progress
        (asyncua fails its pending requests when the session closes)."""
        self._stopped = True
        self.close()

    def touch(self, move: TouchMove) -> TouchReply:
        if self._stopped:
            raise ProbeBackendError("stopped: the probe_cycle node is shutting down")
        client = self._connect()
        args = [ua.Variant(int(move.artefact), ua.VariantType.UInt32),
                ua.Variant(float(move.c_axis_deg), ua.VariantType.Double),
                ua.Variant(float(move.b_axis_deg), ua.VariantType.Double),
                ua.Variant([float(v) for v in move.start_mm], ua.VariantType.Double),
                ua.Variant([float(v) for v in move.direction], ua.VariantType.Double),
                ua.Variant(float(move.max_travel_mm), ua.VariantType.Double)]
        try:
            obj = client.get_node(self.nodes.probe_object)
            out = obj.call_method(ua.NodeId.from_string(self.nodes.probe_method), *args)
        except Exception as exc:  # connection loss, timeout, Bad* status from the CNC
            self.close()
            raise ProbeBackendError(f"{self.nodes.probe_method} on {self.endpoint}: "
                                    f"{exc.__class__.__name__}: {exc}") from exc
        try:
            triggered, position = bool(out[0]), np.asarray(out[1], dtype=float)
        except (TypeError, IndexError, ValueError) as exc:
            raise ProbeBackendError(f"{self.nodes.probe_method} answered {out!r}, expected "
                                    f"(triggered, position_mm[3])") from exc
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise ProbeBackendError(f"{self.nodes.probe_method}: position_mm "
                                    f"{position.tolist()} is not 3 finite values")
        return TouchReply(triggered, position, float(self.clock()))

    def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            try:
                client.disconnect()           # also stops the client's own thread loop
            except Exception as exc:  # already gone: nothing more to release
                log.debug("disconnect: %s", exc)
