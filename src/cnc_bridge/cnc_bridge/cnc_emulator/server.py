"""The emulated CNC: an asyncua OPC UA server with axis positions and temperature-compensation
nodes (:class:`CncEmulator`, async; the address space is described in the package docstring).

Compensation written and enabled is the CNC's applied offset: the ``on_compensation``
callback receives ``{axis: applied_um}`` after every accepted write (the demo feeds it to
the twin). Security (:class:`EmulatorConfig`): ``security='required'`` offers only
Basic256Sha256 Sign&Encrypt and then needs a user and a trust list of client certificates;
``'optional'`` offers it next to None when a certificate is loaded. A trust list, when
given, is checked for every client certificate; logins are gated by
:mod:`cnc_bridge.cnc_emulator.access`. Values outside what a CNC accepts are refused
per node with BadOutOfRange (:func:`cnc_bridge.cnc_emulator.nodes.write_refusal`).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from asyncua import Server, ua
from asyncua.common.callback import CallbackType

from cnc_bridge.cnc_emulator.access import LoginBackoff, SessionGate
from cnc_bridge.cnc_emulator.nodes import (BAD_OUT_OF_RANGE, COMPENSATION_NODES,
                                           DEFAULT_COMPENSATION_AXES, DEFAULT_OFFSET_LIMIT_MM,
                                           DEFAULT_POSITION_AXES, ENDPOINT_PATH, NAMESPACE_URI,
                                           UM_PER_MM, compensation_node_id, position_node_id,
                                           write_refusal)
from cnc_bridge.cnc_emulator.probe import ProbeMove, ProbeRequest
from cnc_bridge.trust_list import TrustList

log = logging.getLogger("cnc_emulator")

@dataclass
class EmulatorConfig:
    host: str = "127.0.0.1"
    port: int = 4840
    position_axes: Sequence[str] = DEFAULT_POSITION_AXES
    compensation_axes: Sequence[str] = DEFAULT_COMPENSATION_AXES
    user: str | None = None
    password: str | None = None
    certificate: str | None = None
    private_key: str | None = None
    security: str = "optional"           # "required" | "optional"
    client_trust: Sequence[str] = ()     # trust list: folder(s) / files of client certificates
    offset_limit_mm: float = DEFAULT_OFFSET_LIMIT_MM
    login_backoff_s: tuple[float, float] = (0.5, 60.0)   # first and longest back-off, s

    def __post_init__(self):
        if self.security not in ("required", "optional"):
            raise ValueError(f"security: must be 'required' or 'optional', got {self.security!r}")
        if self.security == "required" and not (self.certificate and self.private_key):
            raise ValueError("security 'required' needs --certificate and its private key "
                             "(credentials file or THERMAL_COMP_OPCUA_PRIVATE_KEY)")
        if bool(self.certificate) != bool(self.private_key):
            raise ValueError("certificate and private_key must be given together")
        if (self.user is None) != (self.password is None):
            raise ValueError("user and password must be given together")
        if self.security == "required" and self.user is None:
            raise ValueError("security 'required' needs a user and password (credentials file "
                             "or THERMAL_COMP_OPCUA_USER/PASSWORD): anonymous sessions are refused")
        if self.security == "required" and not self.client_trust:
            raise ValueError("security 'required' needs a trust list of client certificates "
                             "(--client-trust): unknown certificates are refused")
        if not (isinstance(self.offset_limit_mm, (int, float)) and 0 < self.offset_limit_mm < math.inf):
            raise ValueError(f"offset_limit_mm: must be a finite number > 0, got {self.offset_limit_mm!r}")
        if not 0 < int(self.port) < 65536:
            raise ValueError(f"port: must be 1..65535, got {self.port!r}")

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}{ENDPOINT_PATH}"


@dataclass
class EmulatorState:
    """What survives a restart when it is kept (a real CNC keeps setting data in NV memory)."""

    positions: dict[str, float] = field(default_factory=dict)
    compensation: dict[str, dict[str, float]] = field(default_factory=dict)


class CncEmulator:
    """The OPC UA server (async). ``await start()``, ``await stop()``."""

    def __init__(self, config: EmulatorConfig, probe_move: ProbeMove | None = None,
                 on_compensation: Callable[[dict[str, float]], None] | None = None,
                 state: EmulatorState | None = None):
        self.config = config
        self.probe_move = probe_move
        self.on_compensation = on_compensation
        self.state = state or EmulatorState()
        for a in config.position_axes:
            self.state.positions.setdefault(a, 0.0)
        for a in config.compensation_axes:
            self.state.positions.setdefault(a, 0.0)
            comp = self.state.compensation.setdefault(a, {})
            for item in COMPENSATION_NODES:
                comp.setdefault(item, 0.0)
        #: every client write that the server accepted: (node id string, value), in order
        self.write_log: list[tuple[str, float]] = []
        #: per client write request, each axis it touched: (axis, applied um before, after):
        #: what the write did to the machine, whatever the CNC held before (a restart's value)
        self.moves: list[tuple[str, float, float]] = []
        #: every client write refused as out of range: (node id string, value, reason)
        self.refused_writes: list[tuple[str, object, str]] = []
        self.trust = TrustList.from_paths(config.client_trust, "client trust list") \
            if config.client_trust else None
        self.gate = SessionGate(config.user, config.password, config.security == "required",
                                LoginBackoff(*config.login_backoff_s), trust=self.trust)
        self._server: Server | None = None
        self._nodes: dict[str, object] = {}
        #: node id string -> NodeId of the nodes the server updates itself (parsed once)
        self._node_ids: dict[str, ua.NodeId] = {}

    # ---------------------------------------------------------------- address space
    async def start(self) -> None:
        cfg = self.config
        server = Server(user_manager=self.gate)
        await server.init()
        self.gate.attach(server.iserver)
        if self.trust is not None:
            server.set_certificate_validator(self.trust)
        self._guard_writes(server)
        server.set_endpoint(cfg.endpoint)
        server.set_server_name("thermal-comp CNC emulator")
        await server.set_application_uri("urn:thermal-comp:cnc-emulator:server")
        policies = []
        if cfg.certificate:
            await server.load_certificate(cfg.certificate)
            await server.load_private_key(cfg.private_key)
            policies.append(ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt)
        if cfg.security == "optional":
            policies.append(ua.SecurityPolicyType.NoSecurity)
        server.set_security_policy(policies)
        if cfg.user is not None:
            server.set_identity_tokens([ua.UserNameIdentityToken])
        idx = await server.register_namespace(NAMESPACE_URI)
        if idx != 2:
            raise RuntimeError(f"namespace index {idx}, expected 2")
        objects = server.nodes.objects
        axes_obj = await objects.add_object(ua.NodeId("Axes", idx), f"{idx}:Axes")
        for a, v in self.state.positions.items():
            self._nodes[position_node_id(a)] = await axes_obj.add_variable(
                ua.NodeId(f"Axis.{a}.Position", idx), f"{idx}:{a}_Position", float(v),
                varianttype=ua.VariantType.Double)
        comp_obj = await objects.add_object(ua.NodeId("TempComp", idx), f"{idx}:TempComp")
        for a, comp in self.state.compensation.items():
            for item in COMPENSATION_NODES:
                vtype = ua.VariantType.Int32 if item == "MD32750" else ua.VariantType.Double
                value = int(comp[item]) if item == "MD32750" else float(comp[item])
                node = await comp_obj.add_variable(
                    ua.NodeId(f"TempComp.{a}.{item}", idx), f"{idx}:{a}_{item}", value,
                    varianttype=vtype)
                await node.set_writable()
                self._nodes[compensation_node_id(a, item)] = node
            self._nodes[compensation_node_id(a, "Applied")] = await comp_obj.add_variable(
                ua.NodeId(f"TempComp.{a}.Applied", idx), f"{idx}:{a}_Applied",
                self._applied_mm(a), varianttype=ua.VariantType.Double)
        if self.probe_move is not None:
            probe_obj = await objects.add_object(ua.NodeId("Probe", idx), f"{idx}:Probe")

            def arg(name, vtype, n=None):
                a = ua.Argument()
                a.Name = name
                a.DataType = ua.NodeId(vtype.value)
                a.ValueRank = -1 if n is None else 1
                a.ArrayDimensions = [] if n is None else [n]
                return a
            D = ua.VariantType.Double
            await probe_obj.add_method(
                ua.NodeId("Probe.ProbeMove", idx), f"{idx}:ProbeMove", self._probe_call,
                [arg("artefact", ua.VariantType.UInt32), arg("c_axis_deg", D), arg("b_axis_deg", D),
                 arg("start_mm", D, 3), arg("direction", D, 3), arg("max_travel_mm", D)],
                [arg("triggered", ua.VariantType.Boolean), arg("position_mm", D, 3)])
        self._node_ids = {nid: ua.NodeId.from_string(nid) for nid in self._nodes}
        server.subscribe_server_callback(CallbackType.PostWrite, self._after_write)
        await server.start()
        self._server = server
        log.info("CNC emulator listening on %s", cfg.endpoint)

    async def stop(self) -> None:
        if self._server is not None:
            server, self._server = self._server, None
            await server.stop()

    # ---------------------------------------------------------------- behaviour
    def _guard_writes(self, server: Server) -> None:
        """Answer BadOutOfRange for compensation values a CNC would not take (nothing changes)."""
        service = server.iserver.attribute_service
        write = service.write

        async def guarded(params, user=None, **kw):
            verdicts = []
            for wv in params.NodesToWrite:
                verdicts.append(None)
                nid = wv.NodeId.to_string()
                if wv.AttributeId == ua.AttributeIds.Value and nid.startswith("ns=2;s=TempComp."):
                    item = nid.rsplit(".", 1)[1]
                    value = wv.Value.Value.Value if wv.Value and wv.Value.Value else None
                    why = write_refusal(item, value, self.config.offset_limit_mm)
                    if why is not None and item in COMPENSATION_NODES:
                        self.refused_writes.append((nid, value, why))
                        log.warning("refused write of %s: %s", nid, why)
                        verdicts[-1] = BAD_OUT_OF_RANGE
            ok = [wv for wv, v in zip(params.NodesToWrite, verdicts) if v is None]
            args = {} if user is None else {"user": user}
            results = iter(await write(dataclasses.replace(params, NodesToWrite=ok), **args, **kw)
                           if ok else [])
            return [v if v is not None else next(results) for v in verdicts]
        service.write = guarded

    def _applied_mm(self, axis: str) -> float:
        c = self.state.compensation[axis]
        if int(c["MD32750"]) == 0:
            return 0.0
        return c["SD43900"] + c["SD43910"] * (self.state.positions[axis] - c["SD43920"])

    def applied_um(self) -> dict[str, float]:
        """Compensation the CNC applies now, axis -> um."""
        return {a: self._applied_mm(a) * UM_PER_MM for a in self.state.compensation}

    async def _refresh_applied(self, axes=None) -> None:
        """Update the ``Applied`` node of ``axes`` (default: every axis), then tell the hook."""
        for a in self.state.compensation if axes is None else axes:
            await self._write_internal(compensation_node_id(a, "Applied"), self._applied_mm(a))
        if self.on_compensation is not None:
            self.on_compensation(self.applied_um())

    async def _write_internal(self, node_id: str, value: float) -> None:
        # the server's own update: straight into the address space (no service, no callback)
        await self._server.write_attribute_value(
            self._node_ids[node_id], ua.DataValue(ua.Variant(value, ua.VariantType.Double)))

    async def _after_write(self, event, _dispatcher) -> None:
        if not event.is_external:       # the server's own updates of Applied/Position
            return
        changed: list[str] = []
        before = self.applied_um()
        for wv, status in zip(event.request_params.NodesToWrite, event.response_params):
            if not status.is_good() or wv.AttributeId != ua.AttributeIds.Value:
                continue
            nid = wv.NodeId.to_string()
            value = wv.Value.Value.Value
            self.write_log.append((nid, value))
            if nid.startswith("ns=2;s=TempComp."):
                _, axis, item = wv.NodeId.Identifier.split(".")
                self.state.compensation[axis][item] = float(value)
                if axis not in changed:
                    changed.append(axis)
        if changed:      # only the written axes: a position change refreshes them all
            after = self.applied_um()
            self.moves.extend((a, before[a], after[a]) for a in changed)
            await self._refresh_applied(changed)

    async def set_position(self, axis: str, value: float) -> None:
        """Move an axis (the machine's own motion; clients only read positions)."""
        if axis not in self.state.positions:
            raise KeyError(f"unknown axis {axis!r} (have {sorted(self.state.positions)})")
        self.state.positions[axis] = float(value)
        if self._server is not None and position_node_id(axis) in self._nodes:
            await self._write_internal(position_node_id(axis), float(value))
            if axis in self.state.compensation:
                await self._refresh_applied()

    async def _probe_call(self, parent, artefact, c_deg, b_deg, start, direction, max_travel):
        vals = [v.Value for v in (artefact, c_deg, b_deg, start, direction, max_travel)]
        try:
            for axis, angle in (("C", vals[1]), ("B", vals[2])):
                if axis in self.state.positions:
                    await self.set_position(axis, angle)
            req = ProbeRequest(int(vals[0]), float(vals[1]), float(vals[2]),
                               np.asarray(vals[3], dtype=float), np.asarray(vals[4], dtype=float),
                               float(vals[5]), self.applied_um())
            triggered, pos = self.probe_move(req)
        except (ValueError, TypeError) as exc:     # bad arguments: a clear OPC UA error
            log.warning("ProbeMove refused: %s", exc)
            raise ua.UaStatusCodeError(ua.StatusCodes.BadInvalidArgument) from exc
        pos = [float(p) for p in pos]
        return [ua.Variant(bool(triggered), ua.VariantType.Boolean),
                ua.Variant(pos, ua.VariantType.Double)]


