"""OPC UA backend: an asyncua client that writes compensation offsets to a CNC.

* **Node ids** are configurable per axis (:class:`AxisNodes`, loaded from a YAML node-id
  map with :func:`load_node_map`); the default (:func:`default_node_map`) is modelled on
  SINUMERIK's temperature compensation and matches :mod:`cnc_bridge.cnc_emulator`:
  SD43900 offset [mm], SD43910 slope, SD43920 reference position [mm], MD32750 enable.
  The bridge computes position-dependent terms itself (eq. 6.3-6.5 at the current
  position), so it writes slope 0, reference position 0 and enable 1 once before its first
  offset write and again on every reconnection after that; every update then writes only
  the offsets.
* **Connecting never writes**: the first connection only reads what the CNC holds
  (:meth:`OpcUaBackend.held_state`: offset and whether compensation is on), so a bridge
  that is configured but not active (lifecycle) never moves the machine. The node adopts
  the held values into its envelope (within its limits) and hands the adopted values back
  (:meth:`OpcUaBackend.adopt`), which are what a re-apply writes.
* **Read-back**: every write is followed by a read of the same nodes, pipelined behind it
  on the same channel (one WriteRequest of every axis, one ReadRequest: one round trip); an
  axis counts as applied only if its write status is Good and the value read equals the
  value written (:meth:`OpcUaBackend._write_and_read`). The backend returns the read-back
  in um, or None for an axis whose write was not confirmed.
* **Reconnect**: a supervisor task checks the session (a read of the server's state every
  ``check_period_s`` in which no write was answered: while writes flow, their answers prove
  the session and a failed write marks it lost at once), and on any failure disconnects,
  waits with exponential back-off, reconnects and re-creates the subscription on the axis
  positions. A reconnection is a start-up again: it only reads what the CNC holds now (a
  CNC that restarted may hold 0, a stale value, compensation off, a value beyond the
  envelope) and writes nothing until the caller adopted it (:attr:`reconnect_pending`,
  :func:`cnc_bridge.offset_backend.adopt_held_state`, the rule of the first start-up); the
  next write then re-arms (slope 0, reference 0, the adopted offsets, enable 1) and the
  envelope ramps from there. Writes asked for while disconnected or before that adoption
  fail at once (never queued and replayed later, so none is applied twice or late).
* **Security**: user name/password and Basic256Sha256 Sign&Encrypt with certificates;
  ``security_required`` refuses to connect without it, and then needs a user and a trust
  list of server certificates (:mod:`cnc_bridge.trust_list`) or one pinned certificate:
  a server whose certificate is not listed is refused before any session.
* The public methods are synchronous, with deadlines, so a ROS node stays single-threaded.
  The asyncio client's loop runs either in a dedicated thread (default) or, with
  ``inline=True``, in the caller's own thread (:class:`cnc_bridge.loop_thread.InlineLoop`):
  a write then runs to completion there without a hop between threads, and the caller
  calls :meth:`OpcUaBackend.serve` periodically so that the health check, keep-alives,
  position updates and a reconnection go on between writes (the cnc_bridge node does).
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
import threading
import time
from typing import Mapping

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from cnc_bridge.loop_thread import InlineLoop, LoopThread
from cnc_bridge.opcua_config import OpcUaConfig, OpcUaConfigError
from cnc_bridge.trust_list import TrustList

log = logging.getLogger("cnc_bridge.opcua")


#: period of asyncua's own server-state probe, s: far beyond ``check_period_s``, so that the
#: backend's supervisor is the one health check (asyncua still reports a closed transport at once)
LIBRARY_WATCHDOG_S = 60.0


class _PositionHandler:
    def __init__(self, backend: "OpcUaBackend", by_node: dict[str, str]):
        self._backend, self._by_node = backend, by_node

    def datachange_notification(self, node, val, data):
        axis = self._by_node.get(node.nodeid.to_string())
        if axis is not None and isinstance(val, (int, float)):
            self._backend._positions[axis] = float(val)

    def status_change_notification(self, status):
        # the server changed our subscription's status (closed, timed out): start over
        log.warning("subscription status changed: %s", status)
        self._backend._mark_lost()   # called on the client's own loop


class OpcUaBackend:
    """CncBackend over OPC UA; see the module docstring."""

    name = "opcua"

    def __init__(self, config: OpcUaConfig, inline: bool = False):
        self.config = config
        self._offset_axes = [a for a, n in config.node_map.items() if n.offset]
        self._offset_ids = {a: ua.NodeId.from_string(config.node_map[a].offset) for a in self._offset_axes}
        #: the last update's write + read-back, as the client's loop saw it (for the profile)
        self.last_round_trip_s = 0.0
        self.last_round_trips = 0
        self._positions: dict[str, float] = {}
        self._confirmed_um: dict[str, float] = {}
        self.connections = 0                  # successful (re)connections so far
        self.last_error: str = ""
        self._client: Client | None = None
        self._connected = threading.Event()
        self._lost: asyncio.Event | None = None
        self._lock: asyncio.Lock | None = None
        self._closing = False
        self._armed = False                   # set by the first write after each connection
        #: monotonic time of the server's last answer to a write: the health check reads the
        #: server's state only when no write was answered within ``check_period_s``
        self._answered_at = -math.inf
        self._held: dict[str, tuple[float, bool]] = {}
        #: reconnected, and what the CNC holds now not yet adopted: no write until it is
        self._reconnect_pending = False
        self._trust = TrustList.from_paths(config.server_trust, "server trust list") \
            if config.server_trust else None
        self._io = InlineLoop("opcua-client") if inline else LoopThread("opcua-client")
        self._loop = self._io.loop
        self._supervisor = self._io.submit(self._supervise())

    # ------------------------------------------------------------------ public, sync
    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def wait_connected(self, timeout_s: float) -> bool:
        return self._io.wait(self._connected, timeout_s)

    #: how long one :meth:`serve` drives an inline loop. Connected: 0, run what is ready (an
    #: answer that arrived, a timer that fell due, a publish request to send) and return;
    #: the next serve or write goes on from there, so a serve is one wake, not a 1 ms sleep
    #: in the executor's thread. Reconnecting: a handshake of round trips, 20 ms
    SERVE_CONNECTED_S, SERVE_RECONNECTING_S = 0.0, 0.02

    def serve(self) -> None:
        """Inline loop: run the client's background tasks for a moment (call it every few
        tens of ms); a no-op with the loop in its own thread."""
        self._io.serve(self.SERVE_CONNECTED_S if self._connected.is_set() else self.SERVE_RECONNECTING_S)

    def axis_positions(self) -> dict[str, float]:
        return dict(self._positions)

    def write_offsets(self, offsets_um: Mapping[str, float]) -> dict[str, float | None]:
        unknown = set(offsets_um) - set(self._offset_axes)
        if unknown:
            raise OpcUaConfigError(
                f"no offset node for axis {sorted(unknown)} in the node map (have {self._offset_axes})")
        if not self._connected.is_set():
            return {a: None for a in offsets_um}
        try:
            return self._io.run(self._write(dict(offsets_um)), self.config.timeout_s * 2 + 1.0)
        except concurrent.futures.TimeoutError:
            self.last_error = "write timed out"
            return {a: None for a in offsets_um}

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        self._supervisor.cancel()
        try:
            self._io.run(self._disconnect(), 5.0)
        except Exception:
            pass   # closing anyway
        self._io.stop()

    # ------------------------------------------------------------------ async internals
    async def _connect(self) -> Client:
        cfg = self.config
        # asyncua's own watchdog would read the server's state every second beside ours
        # (a round trip on the offsets' channel): ours (_supervise) is the health check
        client = Client(cfg.endpoint, timeout=cfg.timeout_s, watchdog_intervall=LIBRARY_WATCHDOG_S)
        client.application_uri = cfg.application_uri
        if self._trust is not None:
            client.certificate_validator = self._trust
        if cfg.user is not None:
            client.set_user(cfg.user)
            client.set_password(cfg.password)
        if cfg.certificate:
            await client.set_security(SecurityPolicyBasic256Sha256, certificate=cfg.certificate,
                                      private_key=cfg.private_key,
                                      server_certificate=cfg.server_certificate,
                                      mode=ua.MessageSecurityMode.SignAndEncrypt)
        await client.connect()
        try:
            if cfg.security_required and client.security_policy.Mode != \
                    ua.MessageSecurityMode.SignAndEncrypt:
                raise OpcUaConfigError("security_required but the channel is not Sign&Encrypt")
            await self._subscribe_positions(client)
            await self._read_held(client)     # connecting never writes
            if self.connections > 0:          # a reconnection: the caller adopts what is held
                self._armed, self._reconnect_pending = False, True
        except BaseException:
            await client.disconnect()
            raise
        return client

    async def _subscribe_positions(self, client: Client) -> None:
        by_node = {n.position: a for a, n in self.config.node_map.items() if n.position}
        if not by_node:
            return
        sub = await client.create_subscription(100, _PositionHandler(self, by_node))
        await sub.subscribe_data_change([client.get_node(n) for n in by_node])

    async def _read_held(self, client: Client) -> None:
        """Before this bridge's first write: what the CNC holds (offset, compensation on/off).
        The held offsets also count as confirmed until :meth:`adopt` replaces them."""
        scale = self.config.offset_units_per_um
        axes = [a for a in self._offset_axes if self.config.node_map[a].offset]
        if not axes:
            return
        got = await client.read_values([client.get_node(self.config.node_map[a].offset) for a in axes])
        enables = {}
        with_enable = [a for a in axes if self.config.node_map[a].enable]
        if with_enable:
            vals = await client.read_values(
                [client.get_node(self.config.node_map[a].enable) for a in with_enable])
            enables = dict(zip(with_enable, vals))
        for a, v in zip(axes, got):
            try:
                um = float(v) / scale
            except (TypeError, ValueError):
                um = math.nan
            on = True if a not in enables else _as_int(enables[a]) != 0
            self._held[a] = (um, on)
            if math.isfinite(um):
                self._confirmed_um[a] = um if on else 0.0

    def held_state(self) -> dict[str, tuple[float, bool]]:
        """What the CNC held at this bridge's last connection: axis -> (offset um, compensation on)."""
        return dict(self._held)

    @property
    def reconnect_pending(self) -> bool:
        """Reconnected and the held state not adopted yet (:meth:`adopt`): writes are refused."""
        return self._reconnect_pending

    def held_offsets(self) -> dict[str, float]:
        """Offsets the CNC confirmed holding (um) in effect (0 where compensation was off)."""
        return dict(self._confirmed_um)

    def adopt(self, adopted_um: Mapping[str, float]) -> None:
        """The envelope's adopted values become what a (re-)apply writes (the held offsets in
        effect); after a reconnection this lets writes through again."""
        for a, v in adopted_um.items():
            if a in self._offset_axes and math.isfinite(float(v)):
                self._confirmed_um[a] = float(v)
        self._reconnect_pending = False

    async def _reapply(self, client: Client) -> None:
        """Before the first write after a (re)connection: slope 0, reference 0, the adopted
        offsets (what the CNC holds in effect: no axis moves), enable 1."""
        nodes, values = [], []
        scale = self.config.offset_units_per_um
        for a in self._offset_axes:
            n = self.config.node_map[a]
            for nid, v, vt in ((n.slope, 0.0, ua.VariantType.Double),
                               (n.ref_position, 0.0, ua.VariantType.Double),
                               (n.offset, self._confirmed_um.get(a, 0.0) * scale, ua.VariantType.Double),
                               (n.enable, 1, ua.VariantType.Int32)):
                if nid:
                    nodes.append(client.get_node(nid))
                    values.append(ua.DataValue(ua.Variant(v, vt)))
        await client.write_values(nodes, values)
        back = await client.read_values(nodes)
        for node, want, got in zip(nodes, values, back):
            if not _equal(want.Value.Value, got, self.config.readback_tolerance):
                raise ConnectionError(f"re-apply of {node.nodeid.to_string()} not confirmed: "
                                      f"wrote {want.Value.Value!r}, read {got!r}")

    async def _write(self, offsets_um: dict[str, float]) -> dict[str, float | None]:
        scale = self.config.offset_units_per_um
        async with self._lock:
            client = self._client
            if client is None or not self._connected.is_set():
                return {a: None for a in offsets_um}
            axes = list(offsets_um)
            if self._reconnect_pending:
                self.last_error = ("reconnected: what the CNC holds now is not adopted yet; "
                                   "nothing written")
                return {a: None for a in axes}
            if not self._armed:
                # the first write of this bridge: offsets (the adopted ones) before enable 1
                try:
                    await asyncio.wait_for(self._reapply(client), self.config.timeout_s * 2)
                except (Exception, asyncio.TimeoutError) as exc:
                    self.last_error = f"first write (slope 0, reference 0, enable 1) failed: {exc!r}"
                    log.warning("%s", self.last_error)
                    return {a: None for a in axes}
                self._armed = True
            nodeids = [self._offset_ids[a] for a in axes]
            values = [float(offsets_um[a]) * scale for a in axes]
            t0 = time.perf_counter()
            try:
                written, back = await asyncio.wait_for(
                    self._write_and_read(client, nodeids, values), self.config.timeout_s)
            except (Exception, asyncio.TimeoutError) as exc:
                self.last_error = f"write failed: {exc!r}"
                log.warning("%s", self.last_error)
                self._mark_lost()
                return {a: None for a in axes}
            self.last_round_trip_s = time.perf_counter() - t0
            self._answered_at = time.monotonic()
            out: dict[str, float | None] = {}
            for a, want, status, got in zip(axes, values, written, back):
                if status.is_good() and _read_equal(want, got, self.config.readback_tolerance):
                    out[a] = float(got.Value.Value) / scale
                    self._confirmed_um[a] = out[a]
                else:
                    self.last_error = (f"axis {a}: wrote {want!r} ({status.name}), "
                                       f"read back {_read_text(got)}")
                    out[a] = None
            return out

    async def _write_and_read(self, client: Client, nodeids: list, values: list[float]):
        """One WriteRequest of every axis and, pipelined behind it on the same channel, one
        ReadRequest of the same nodes: one round trip. (write statuses, read DataValues)

        OPC UA does not promise that a server answers requests in the order they were sent
        (asyncua's server, like most, does): an axis whose write was accepted but whose
        pipelined read disagrees is read once more, after the write's response, before it
        counts as not confirmed. So an axis is confirmed only by a read that the server
        answered with the value written, and never on the write's status alone."""
        uac = client.uaclient
        dvs = [ua.DataValue(ua.Variant(v, ua.VariantType.Double)) for v in values]
        self.last_round_trips = 1
        # the write is sent first: asyncio runs the two tasks in the order they were created
        answers = await asyncio.gather(uac.write_attributes(nodeids, dvs, ua.AttributeIds.Value),
                                       uac.read_attributes(nodeids, ua.AttributeIds.Value),
                                       return_exceptions=True)     # both settle: no orphan task
        for answer in answers:
            if isinstance(answer, BaseException):
                raise answer
        written, back = answers
        again = [i for i, (want, status, got) in enumerate(zip(values, written, back))
                 if status.is_good() and not _read_equal(want, got, self.config.readback_tolerance)]
        if again:
            self.last_round_trips = 2
            reread = await uac.read_attributes([nodeids[i] for i in again], ua.AttributeIds.Value)
            back = list(back)
            for i, dv in zip(again, reread):
                back[i] = dv
        return written, back

    def _mark_lost(self) -> None:
        self._connected.clear()
        if self._lost is not None:
            self._lost.set()

    async def _disconnect(self) -> None:
        self._connected.clear()
        client, self._client = self._client, None
        if client is not None:
            try:
                await asyncio.wait_for(client.disconnect(), self.config.timeout_s)
            except (Exception, asyncio.TimeoutError):
                pass   # the server is gone already; the socket is closed either way

    async def _supervise(self) -> None:
        cfg = self.config
        self._lock = asyncio.Lock()
        self._lost = asyncio.Event()
        backoff = cfg.reconnect_min_s
        while True:
            try:
                async with self._lock:
                    self._client = await asyncio.wait_for(self._connect(), cfg.timeout_s * 3)
                    self._lost.clear()
                    self.connections += 1
                    self._connected.set()
                log.info("connected to %s (connection %d)", cfg.endpoint, self.connections)
                backoff = cfg.reconnect_min_s
                while not self._lost.is_set():
                    try:
                        await asyncio.wait_for(self._lost.wait(), cfg.check_period_s)
                    except asyncio.TimeoutError:
                        if time.monotonic() - self._answered_at < cfg.check_period_s:
                            continue      # a write's answer within the period proved the session
                        async with self._lock:
                            await asyncio.wait_for(
                                self._client.nodes.server_state.read_value(), cfg.timeout_s)
            except asyncio.CancelledError:
                raise
            except OpcUaConfigError as exc:
                self.last_error = str(exc)
            except (Exception, asyncio.TimeoutError) as exc:
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.warning("OPC UA connection to %s: %s; retrying in %.1f s",
                            cfg.endpoint, self.last_error, backoff)
            self._connected.clear()
            await self._disconnect()
            await asyncio.sleep(backoff)
            backoff = min(backoff * 2.0, cfg.reconnect_max_s)


def _as_int(v) -> int:
    try:
        return int(v)
    except (TypeError, ValueError):
        return 1      # unreadable: assume compensation on (beyond the limit: activation refused)


def _read_equal(want: float, got: ua.DataValue, tol: float) -> bool:
    """A read answered Good with ``want`` (within ``tol``)."""
    status = got.StatusCode if got.StatusCode is not None else ua.StatusCode()
    return status.is_good() and got.Value is not None and _equal(want, got.Value.Value, tol)


def _read_text(got: ua.DataValue) -> str:
    status = got.StatusCode if got.StatusCode is not None else ua.StatusCode()
    value = got.Value.Value if got.Value is not None else None
    return f"{value!r}" if status.is_good() else f"{value!r} ({status.name})"


def _equal(want, got, tol: float) -> bool:
    try:
        return abs(float(want) - float(got)) <= tol
    except (TypeError, ValueError):
        return False
