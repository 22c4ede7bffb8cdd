"""CNC emulator: an asyncua OPC UA server with axis positions and temperature-compensation nodes.

``thermal-comp cnc-emulator`` runs it from the command line; :class:`CncEmulator` (async) and
:class:`CncEmulatorThread` (own thread and event loop, start/stop/restart from synchronous
code) use it as a library, e.g. in tests and the demo.

Address space (namespace ``urn:thermal-comp:cnc-emulator``, registered first, so its index
is 2 and the ids below are ``ns=2;s=...``; ``<A>`` is an axis name such as ``X`` or, on a
lathe, ``GB_X``/``T01_X``). The compensation nodes are modelled on SINUMERIK's temperature
compensation:

==================================  ========  ======  ===================================================
node id                             type      access  meaning
==================================  ========  ======  ===================================================
``ns=2;s=Axis.<A>.Position``        Double    read    axis position, mm (linear) or deg (rotary)
``ns=2;s=TempComp.<A>.SD43900``     Double    write   offset, mm (``$SA_TEMP_COMP_ABS_VALUE``)
``ns=2;s=TempComp.<A>.SD43910``     Double    write   slope, mm/mm (``$SA_TEMP_COMP_SLOPE``)
``ns=2;s=TempComp.<A>.SD43920``     Double    write   reference position, mm (``$SA_TEMP_COMP_REF_POSITION``)
``ns=2;s=TempComp.<A>.MD32750``     Int32     write   compensation type/enable, 0 = off (``$MA_TEMP_COMP_TYPE``)
``ns=2;s=TempComp.<A>.Applied``     Double    read    compensation the CNC applies now, mm:
                                                      ``SD43900 + SD43910 * (pos - SD43920)`` if
                                                      MD32750 != 0, else 0
``ns=2;s=Probe.ProbeMove``          Method    call    optional probing interface, see below
==================================  ========  ======  ===================================================

Probing (present only when a ``probe_move`` callable is given): the method
``ProbeMove(artefact: UInt32, c_axis_deg: Double, b_axis_deg: Double, start_mm: Double[3],
direction: Double[3], max_travel_mm: Double) -> (triggered: Boolean, position_mm: Double[3])``
on object ``ns=2;s=Probe`` runs one G31-like skip move: the CNC first turns C and B to the
given angles (the ``Axis.C/B.Position`` nodes follow), then moves from ``start_mm`` along
``direction``; the answer is the axis position read at the skip (or the end of the move if
nothing triggered). The arguments follow thermal_comp_msgs/TouchProbe.srv (artefact 0 =
sphere, 1 = guide bush). The answer comes from the Python callable
``probe_move(ProbeRequest) -> (bool, position_mm[3])``; :func:`artefact_probe` builds one
from ``thermal_twin.artefact_geometry`` and a provider of the true errors, with the
compensation the emulator currently applies.

Compensation written and enabled is the CNC's applied offset: the ``on_compensation``
callback receives ``{axis: applied_um}`` after every write (the demo feeds it to the twin).
Security: ``security='required'`` offers only Basic256Sha256 Sign&Encrypt (a connection
without it is refused); ``'optional'`` offers it next to None when a certificate is loaded.
With ``user``/``password`` set, only that user may open a session.
"""
from __future__ import annotations

import argparse
import asyncio
import logging
import math
import signal
import socket
import sys
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
from asyncua import Server, ua
from asyncua.common.callback import CallbackType
from asyncua.crypto.permission_rules import User, UserRole

from cnc_bridge.loop_thread import LoopThread

NAMESPACE_URI = "urn:thermal-comp:cnc-emulator"
ENDPOINT_PATH = "/thermal-comp/cnc"
COMPENSATION_NODES = ("SD43900", "SD43910", "SD43920", "MD32750")
DEFAULT_POSITION_AXES = ("X", "Y", "Z", "B", "C")
DEFAULT_COMPENSATION_AXES = ("X", "Y", "Z")
UM_PER_MM = 1000.0

log = logging.getLogger("cnc_emulator")


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` that is free right now (bind port 0, read it, close)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def position_node_id(axis: str, ns: int = 2) -> str:
    return f"ns={ns};s=Axis.{axis}.Position"


def compensation_node_id(axis: str, item: str, ns: int = 2) -> str:
    """``item`` is one of SD43900, SD43910, SD43920, MD32750, Applied."""
    return f"ns={ns};s=TempComp.{axis}.{item}"


PROBE_OBJECT_ID = "ns=2;s=Probe"
PROBE_METHOD_ID = "ns=2;s=Probe.ProbeMove"


@dataclass(frozen=True)
class ProbeRequest:
    """One probing move asked for through ``ProbeMove``."""

    artefact: int
    c_axis_deg: float
    b_axis_deg: float
    start_mm: np.ndarray
    direction: np.ndarray
    max_travel_mm: float
    applied_offsets_um: Mapping[str, float]   # compensation the CNC applies at this moment


ProbeMove = Callable[[ProbeRequest], "tuple[bool, Sequence[float]]"]


def artefact_probe(true_errors: Callable[[], Mapping[str, float]], geometry=None,
                   rng: np.random.Generator | None = None) -> ProbeMove:
    """A ``probe_move`` backed by the twin's artefact geometry.

    ``true_errors()`` returns the current true thermal errors (the twin's ground truth in
    the demo; constants from the command line otherwise).
    """
    from thermal_twin.artefact_geometry import touch_trigger_position

    def probe(req: ProbeRequest):
        return touch_trigger_position(req.artefact, req.c_axis_deg, req.b_axis_deg,
                                      req.start_mm, req.direction, req.max_travel_mm,
                                      true_errors(), req.applied_offsets_um, geometry, rng)
    return probe


class _SessionGate:
    """asyncua user manager: who may open a session.

    With security required, a session on a channel without a client certificate (security
    policy None) is refused here, server-side: asyncua would otherwise let a client that
    ignores the endpoint list activate a session over an unsecured channel. With a user
    name/password configured, only that user gets in (anonymous sessions are refused).
    """

    def __init__(self, user: str | None, password: str | None, security_required: bool):
        self._user, self._password = user, password
        self._security_required = security_required

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if self._security_required and not certificate:
            log.warning("refused a session on an unsecured channel (security required)")
            return None
        if self._user is None:
            return User(role=UserRole.User)
        if username == self._user and password == self._password:
            return User(role=UserRole.User, name=username)
        log.warning("refused session for user %r", username)
        return None


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

    def __post_init__(self):
        if self.security not in ("required", "optional"):
            raise ValueError(f"security: must be 'required' or 'optional', got {self.security!r}")
        if self.security == "required" and not (self.certificate and self.private_key):
            raise ValueError("security 'required' needs --certificate and --private-key")
        if bool(self.certificate) != bool(self.private_key):
            raise ValueError("certificate and private_key must be given together")
        if (self.user is None) != (self.password is None):
            raise ValueError("user and password must be given together")
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
        self._server: Server | None = None
        self._nodes: dict[str, object] = {}

    # ---------------------------------------------------------------- address space
    async def start(self) -> None:
        cfg = self.config
        server = Server(user_manager=_SessionGate(cfg.user, cfg.password, cfg.security == "required"))
        await server.init()
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
        server.subscribe_server_callback(CallbackType.PostWrite, self._after_write)
        await server.start()
        self._server = server
        log.info("CNC emulator listening on %s", cfg.endpoint)

    async def stop(self) -> None:
        if self._server is not None:
            server, self._server = self._server, None
            await server.stop()

    # ---------------------------------------------------------------- behaviour
    def _applied_mm(self, axis: str) -> float:
        c = self.state.compensation[axis]
        if int(c["MD32750"]) == 0:
            return 0.0
        return c["SD43900"] + c["SD43910"] * (self.state.positions[axis] - c["SD43920"])

    def applied_um(self) -> dict[str, float]:
        """Compensation the CNC applies now, axis -> um."""
        return {a: self._applied_mm(a) * UM_PER_MM for a in self.state.compensation}

    async def _refresh_applied(self) -> None:
        for a in self.state.compensation:
            await self._write_internal(compensation_node_id(a, "Applied"), self._applied_mm(a))
        if self.on_compensation is not None:
            self.on_compensation(self.applied_um())

    async def _write_internal(self, node_id: str, value: float) -> None:
        await self._server.write_attribute_value(
            ua.NodeId.from_string(node_id), ua.DataValue(ua.Variant(value, ua.VariantType.Double)))

    async def _after_write(self, event, _dispatcher) -> None:
        if not event.is_external:       # the server's own updates of Applied/Position
            return
        changed = False
        for wv, status in zip(event.request_params.NodesToWrite, event.response_params):
            if not status.is_good() or wv.AttributeId != ua.AttributeIds.Value:
                continue
            nid = wv.NodeId.to_string()
            value = wv.Value.Value.Value
            self.write_log.append((nid, value))
            if nid.startswith("ns=2;s=TempComp."):
                _, axis, item = wv.NodeId.Identifier.split(".")
                self.state.compensation[axis][item] = float(value)
                changed = True
        if changed:
            await self._refresh_applied()

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


class CncEmulatorThread:
    """:class:`CncEmulator` in its own thread and event loop, driven from synchronous code.

    ``restart(keep_state=False)`` emulates a CNC whose compensation was reset to zero.
    """

    def __init__(self, config: EmulatorConfig, probe_move: ProbeMove | None = None,
                 on_compensation: Callable[[dict[str, float]], None] | None = None):
        self.config = config
        self._probe_move = probe_move
        self._on_comp = on_compensation
        self._io = LoopThread("cnc-emulator")
        self.emulator: CncEmulator | None = None
        self.write_log: list[tuple[str, float]] = []   # accumulated over restarts

    def _run(self, coro, timeout: float = 20.0):
        return self._io.run(coro, timeout)

    def start(self, state: EmulatorState | None = None) -> "CncEmulatorThread":
        self.emulator = CncEmulator(self.config, self._probe_move, self._on_comp, state)
        self.emulator.write_log = self.write_log
        self._run(self.emulator.start())
        return self

    def stop(self) -> None:
        if self.emulator is not None:
            self._run(self.emulator.stop())

    def restart(self, keep_state: bool = True) -> None:
        state = self.emulator.state if keep_state else None
        self.stop()
        self.start(state)

    def close(self) -> None:
        self.stop()
        self._io.stop()

    def applied_um(self) -> dict[str, float]:
        return self._run(_call(self.emulator.applied_um))

    def set_position(self, axis: str, value: float) -> None:
        self._run(self.emulator.set_position(axis, value))

    def set_positions(self, positions: Mapping[str, float]) -> None:
        """Move several axes in one hop to the emulator's loop."""
        async def move():
            for axis, value in positions.items():
                await self.emulator.set_position(axis, value)
        self._run(move())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


async def _call(fn):
    return fn()


def _parse_errors(text: str) -> dict[str, float]:
    out = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--true-errors: '{item}' is not NAME=NUMBER") from None
        if not sep or not math.isfinite(out[name.strip()]):
            raise argparse.ArgumentTypeError(f"--true-errors: '{item}' is not NAME=NUMBER")
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="thermal-comp cnc-emulator",
        description="OPC UA CNC emulator: axis positions and SINUMERIK-like temperature-"
                    "compensation nodes (SD43900/43910/43920, MD32750) on 127.0.0.1; "
                    "optional ProbeMove method. Node ids: see docs/cnc_bridge.md.")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=4840, help="TCP port (default 4840)")
    p.add_argument("--user", help="user name a client must log in with")
    p.add_argument("--password", help="password of --user")
    p.add_argument("--certificate", help="server certificate (DER or PEM) for Basic256Sha256")
    p.add_argument("--private-key", help="private key (PEM) of --certificate")
    p.add_argument("--security", choices=("required", "optional"), default="optional",
                   help="required: only Basic256Sha256 Sign&Encrypt connections are accepted")
    p.add_argument("--axes", default=",".join(DEFAULT_POSITION_AXES),
                   help="axes with a position node (comma-separated)")
    p.add_argument("--compensation-axes", default=",".join(DEFAULT_COMPENSATION_AXES),
                   help="axes with temperature-compensation nodes, e.g. X,Y,Z or GB_X,T01_X")
    p.add_argument("--probe-artefact", action="store_true",
                   help="offer ProbeMove, answered by the twin's artefact geometry with the "
                        "errors of --true-errors and the compensation currently applied")
    p.add_argument("--true-errors", type=_parse_errors, default={},
                   help="true thermal errors for --probe-artefact, e.g. E_Z0T=12,E_Y0C=-4 "
                        "(um, um/m)")
    p.add_argument("--twin", action="store_true",
                   help="feed the emulator from the running twin over ROS: machine_state -> axis "
                        "positions, errors/ground_truth -> ProbeMove answers (implies ProbeMove); "
                        "ROS arguments follow --ros-args")
    p.add_argument("-v", "--verbose", action="store_true", help="log every session and write")
    return p


def _serve_twin(cfg: EmulatorConfig, ros_args: list[str]) -> int:
    """Serve the CNC fed by the twin until Ctrl-C / SIGTERM (an rclpy node in this process)."""
    from thermal_comp_common.node_runtime import run_node

    from cnc_bridge.cnc_twin_feed_node import CncTwinFeed
    latest: list[dict[str, float]] = [{}]     # replaced whole by the feed (atomic), read by ProbeMove
    emu = CncEmulatorThread(cfg, probe_move=artefact_probe(lambda: latest[0]))
    try:
        emu.start()
    except OSError as exc:
        print(f"cnc-emulator: cannot listen on {cfg.endpoint}: {exc}", file=sys.stderr)
        emu.close()
        return 1
    print(f"CNC emulator listening on {cfg.endpoint}", flush=True)

    def feed(context):
        return CncTwinFeed(context=context, emulator=emu,
                           on_true_errors=lambda errors: latest.__setitem__(0, errors))
    feed.__name__ = "cnc-emulator"
    try:
        return run_node(feed, ["cnc-emulator"] + ros_args)
    finally:
        emu.close()


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:
        k = argv.index("--ros-args")
        argv, ros_args = argv[:k], argv[k:]
    args = build_parser().parse_args(argv)
    if ros_args and not args.twin:
        print("cnc-emulator: --ros-args only with --twin", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        cfg = EmulatorConfig(host=args.host, port=args.port,
                             position_axes=tuple(filter(None, args.axes.split(","))),
                             compensation_axes=tuple(filter(None, args.compensation_axes.split(","))),
                             user=args.user, password=args.password, certificate=args.certificate,
                             private_key=args.private_key, security=args.security)
    except ValueError as exc:
        print(f"cnc-emulator: {exc}", file=sys.stderr)
        return 2
    if not args.verbose:
        logging.getLogger("asyncua").setLevel(logging.ERROR)
    if cfg.password is not None and not cfg.certificate:
        print("cnc-emulator: warning: a password without --certificate travels unencrypted",
              file=sys.stderr)
    if args.twin:
        return _serve_twin(cfg, ros_args)
    errors = dict(args.true_errors)
    probe = artefact_probe(lambda: errors) if args.probe_artefact else None

    async def serve() -> None:
        emu = CncEmulator(cfg, probe_move=probe)
        await emu.start()
        print(f"CNC emulator listening on {cfg.endpoint}", flush=True)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            await stop.wait()
        finally:
            await emu.stop()

    try:
        asyncio.run(serve())
    except OSError as exc:
        print(f"cnc-emulator: cannot listen on {cfg.endpoint}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
