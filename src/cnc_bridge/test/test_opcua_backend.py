"""The OPC UA backend against the asyncua CNC emulator: read-back, restart, credentials, security."""
from __future__ import annotations

import asyncio
import logging
import time

import pytest

from cnc_bridge.certificates import make_certificate
from cnc_bridge.cnc_emulator import (ENDPOINT_PATH, PROBE_METHOD_ID, PROBE_OBJECT_ID,
                                     CncEmulatorThread, EmulatorConfig, artefact_probe,
                                     compensation_node_id, free_tcp_port)
from cnc_bridge.opcua_backend import OpcUaBackend
from cnc_bridge.opcua_config import OpcUaConfig, OpcUaConfigError, load_node_map

logging.getLogger("asyncua").setLevel(logging.ERROR)


def wait_for(condition, timeout_s: float, what: str, be: OpcUaBackend | None = None):
    """Poll ``condition``; with ``be``, serve its loop meanwhile (what the node's timer does)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        if be is not None:
            be.serve()
        time.sleep(0.01)


@pytest.fixture
def port():
    return free_tcp_port()


def endpoint(port):
    return f"opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}"


@pytest.fixture
def emulator(port):
    emu = CncEmulatorThread(EmulatorConfig(port=port)).start()
    yield emu
    emu.close()


def backend(port, inline: bool = False, **kw) -> OpcUaBackend:
    kw.setdefault("reconnect_max_s", 0.3)
    return OpcUaBackend(OpcUaConfig(endpoint=endpoint(port), **kw), inline=inline)


#: the client's loop in its own thread, or in the caller's (as the cnc_bridge node runs it)
LOOPS = pytest.mark.parametrize("inline", [False, True], ids=["loop-thread", "inline-loop"])


def offset_writes(emu, axis):
    nid = compensation_node_id(axis, "SD43900")
    return [v for n, v in emu.write_log if n == nid]


@LOOPS
def test_writes_are_read_back_and_the_cnc_applies_them(emulator, port, inline):
    be = backend(port, inline)
    try:
        assert be.wait_connected(10), be.last_error
        back = be.write_offsets({"X": 1.5, "Y": -2.0, "Z": 12.25})
        assert back == pytest.approx({"X": 1.5, "Y": -2.0, "Z": 12.25})
        assert emulator.applied_um() == pytest.approx({"X": 1.5, "Y": -2.0, "Z": 12.25})
        emulator.set_position("Z", -250.0)           # positions arrive by subscription
        wait_for(lambda: be.axis_positions().get("Z") == -250.0, 5, "Z position", be)
        with pytest.raises(OpcUaConfigError, match="B"):
            be.write_offsets({"B": 1.0})              # B has no offset node: a clear error
    finally:
        be.close()


@LOOPS
def test_server_restart_mid_run_loses_no_write_and_duplicates_none(emulator, port, inline):
    be = backend(port, inline)
    try:
        assert be.wait_connected(10), be.last_error
        confirmed = []
        for k in range(1, 6):
            v = be.write_offsets({"X": 0.5 * k})["X"]
            assert v == pytest.approx(0.5 * k)
            confirmed.append(v)
        emulator.stop()                               # the CNC goes away ...
        assert be.write_offsets({"X": 99.0}) == {"X": None}   # ... a write now fails, visibly
        emulator.start()                              # ... and comes back with its compensation reset
        wait_for(lambda: be.connected and be.connections == 2, 15, "reconnection", be)
        # a reconnection only reads: the CNC keeps its 0, no write until what it holds is adopted
        assert be.reconnect_pending and be.held_state()["X"] == (0.0, False)   # reset: off
        assert emulator.applied_um()["X"] == 0.0
        assert be.write_offsets({"X": confirmed[-1]}) == {"X": None}
        assert "not adopted" in be.last_error
        emulator.set_position("Y", 42.0)                                    # re-subscribed
        wait_for(lambda: be.axis_positions().get("Y") == 42.0, 5, "Y position after restart", be)
        be.adopt({a: v for a, (v, _) in be.held_state().items()})         # the envelope adopts 0
        assert not be.reconnect_pending
        for k in range(1, 4):                                              # and ramps from there
            assert be.write_offsets({"X": 0.5 * k})["X"] == pytest.approx(0.5 * k)
            confirmed.append(0.5 * k)
        # the CNC saw: initial state, each confirmed write once, the re-arm at what it held
        # (0), the rest; never 99, never the pre-restart value over the 0 it came back with
        seen = [v * 1000.0 for v in offset_writes(emulator, "X")]
        assert seen == pytest.approx([0.0] + confirmed[:5] + [0.0] + confirmed[5:])
        assert emulator.applied_um()["X"] == pytest.approx(1.5)
        assert max(abs(after - before) for a, before, after in emulator.moves if a == "X") <= 0.5 + 1e-9
    finally:
        be.close()


def test_wrong_credentials_are_rejected(port):
    emu = CncEmulatorThread(EmulatorConfig(port=port, user="cnc", password="s3cret")).start()
    try:
        bad = backend(port, user="cnc", password="wrong")
        try:
            wait_for(lambda: "BadUserAccessDenied" in bad.last_error, 20, "the refusal")
            assert not bad.connected
            assert bad.write_offsets({"X": 1.0}) == {"X": None}
        finally:
            bad.close()
        anonymous = backend(port)
        try:
            wait_for(lambda: "BadIdentityTokenRejected" in anonymous.last_error, 20, "the refusal")
            assert not anonymous.connected
        finally:
            anonymous.close()
        good = backend(port, user="cnc", password="s3cret")
        try:
            assert good.wait_connected(10), good.last_error
            assert good.write_offsets({"X": 1.0}) == {"X": pytest.approx(1.0)}
        finally:
            good.close()
        assert offset_writes(emu, "X")[-1] == pytest.approx(0.001)
    finally:
        emu.close()


async def _session_over_unsecured_channel(url: str, user: str, password: str):
    """A raw client: channel with security policy None, then a session and a write."""
    from asyncua import Client, ua
    c = Client(url)
    await c.connect_socket()
    try:
        await c.send_hello()
        await c.open_secure_channel()            # None policy: allowed for discovery only
        params = ua.CreateSessionParameters(
            ClientNonce=b"\0" * 32, EndpointUrl=url, SessionName="raw",
            RequestedSessionTimeout=60000, MaxResponseMessageSize=0,
            ClientDescription=ua.ApplicationDescription(ApplicationUri="urn:raw",
                                                        ApplicationType=ua.ApplicationType.Client))
        await c.uaclient.create_session(params)
        token = ua.UserNameIdentityToken(PolicyId="username", UserName=user,
                                         Password=password.encode())
        await c.uaclient.activate_session(ua.ActivateSessionParameters(LocaleIds=[],
                                                                       UserIdentityToken=token))
        await c.get_node(compensation_node_id("X", "SD43900")).write_value(
            ua.DataValue(ua.Variant(0.5, ua.VariantType.Double)))
    finally:
        c.disconnect_socket()


def test_unsigned_connection_refused_when_security_is_required(tmp_path, port):
    server_cert, server_key = make_certificate(tmp_path, "cnc", "urn:thermal-comp:cnc-emulator:server",
                                               server=True)
    client_cert, client_key = make_certificate(tmp_path, "bridge", "urn:thermal-comp:cnc-bridge",
                                               server=False)
    emu = CncEmulatorThread(EmulatorConfig(port=port, certificate=server_cert, private_key=server_key,
                                           security="required", user="cnc", password="pw",
                                           client_trust=(client_cert,))).start()
    try:
        plain = backend(port, user="cnc", password="pw")
        try:
            # the client finds no endpoint without security and gives up before a session
            wait_for(lambda: "No matching endpoints" in plain.last_error, 20, "the refusal")
            assert not plain.connected
        finally:
            plain.close()
        assert offset_writes(emu, "X") == []          # nothing reached the CNC unencrypted
        with pytest.raises(OpcUaConfigError, match="refusing an insecure connection"):
            OpcUaConfig(endpoint=endpoint(port), security_required=True)
        # the server itself refuses, even a client that ignores the endpoint list
        with pytest.raises(Exception, match="BadUserAccessDenied"):
            asyncio.run(_session_over_unsecured_channel(endpoint(port), "cnc", "pw"))
        assert offset_writes(emu, "X") == []
        secure = backend(port, user="cnc", password="pw", certificate=client_cert,
                         private_key=client_key, security_required=True, server_trust=(server_cert,))
        try:
            assert secure.wait_connected(15), secure.last_error
            assert secure.write_offsets({"Z": -3.0}) == {"Z": pytest.approx(-3.0)}
        finally:
            secure.close()
        assert emu.applied_um()["Z"] == pytest.approx(-3.0)
    finally:
        emu.close()


def test_probe_move_answers_through_opcua_with_the_applied_compensation(port):
    """The probing interface other nodes use: a real method call, answered by the twin geometry."""
    from asyncua import Client, ua
    from thermal_twin.machine.artefact_geometry import nominal_sphere_centre

    emu = CncEmulatorThread(EmulatorConfig(port=port),
                            probe_move=artefact_probe(lambda: {"E_Z0T": 10.0})).start()
    be = backend(port)

    async def probe_top():
        centre = nominal_sphere_centre(0.0)
        async with Client(endpoint(port)) as c:
            return await c.get_node(PROBE_OBJECT_ID).call_method(
                ua.NodeId.from_string(PROBE_METHOD_ID), ua.Variant(0, ua.VariantType.UInt32),
                0.0, 0.0, [float(centre[0]), float(centre[1]), float(centre[2]) + 50.0],
                [0.0, 0.0, -1.0], 100.0)
    try:
        hit_uncompensated = asyncio.run(probe_top())
        assert be.wait_connected(10), be.last_error
        assert be.write_offsets({"Z": 4.0}) == {"Z": pytest.approx(4.0)}
        hit_compensated = asyncio.run(probe_top())
        assert hit_uncompensated[0] and hit_compensated[0]
        # the probe sees true error minus applied compensation: 10 um -> 6 um (1 um resolution)
        dz_um = (hit_uncompensated[1][2] - hit_compensated[1][2]) * 1000.0
        assert dz_um == pytest.approx(4.0, abs=1.0)
    finally:
        be.close()
        emu.close()


def test_node_map_file_is_validated(tmp_path):
    good = tmp_path / "map.yaml"
    good.write_text("offset_units_per_um: 0.0001\naxes:\n  X: {offset: 'ns=2;s=P.X', enable: 'ns=2;s=P.E'}\n")
    nodes, scale = load_node_map(good)
    assert scale == 0.0001 and nodes["X"].offset == "ns=2;s=P.X" and nodes["X"].slope is None
    bad = tmp_path / "bad.yaml"
    bad.write_text("axes:\n  X: {ofset: 'ns=2;s=P.X'}\n")
    with pytest.raises(OpcUaConfigError, match=r"axes\.X.*ofset"):
        load_node_map(bad)
    bad.write_text("axes:\n  X: {offset: 'ns=2;q=P.X'}\n")
    with pytest.raises(OpcUaConfigError, match=r"axes\.X\.offset"):
        load_node_map(bad)


def test_a_restarted_bridge_continues_from_the_offsets_the_cnc_holds(emulator, port):
    """A new bridge process must not write 0 over offsets the CNC holds (an 8 um jump where
    the rate limit allows far less): it adopts them at its first connection."""
    from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
    first = backend(port)
    try:
        assert first.wait_connected(10), first.last_error
        assert first.write_offsets({"X": 0.0, "Y": 0.0, "Z": 8.0})["Z"] == pytest.approx(8.0)
    finally:
        first.close()
    n_writes = len(offset_writes(emulator, "Z"))
    second = backend(port)
    try:
        assert second.wait_connected(10), second.last_error
        assert second.held_offsets()["Z"] == pytest.approx(8.0)
        assert emulator.applied_um()["Z"] == pytest.approx(8.0)
        assert offset_writes(emulator, "Z")[n_writes:] == [], "connecting never writes"
        env = SafetyEnvelope(EnvelopeConfig(max_rate_um_per_s=0.5, max_step_s=10.0))
        env.adopt_held(second.held_offsets())
        env.step(0.0, {"X": 0.0, "Y": 0.0, "Z": 0.0}, fresh=True)
        step = {d.axis: d.applied_um for d in env.step(1.0, {"X": 0.0, "Y": 0.0, "Z": 0.0}, fresh=True)}
        assert step["Z"] == pytest.approx(7.5), "the move away from the held offset is rate limited"
    finally:
        second.close()


def test_one_round_trip_confirms_and_a_refused_axis_is_not_confirmed(emulator, port):
    """Write and read-back go out together (one round trip); an axis the CNC refuses
    (BadOutOfRange) is not confirmed, the others are, and the session stays up."""
    be = backend(port)
    try:
        assert be.wait_connected(10), be.last_error
        assert be.write_offsets({"X": 1.0, "Y": 2.0, "Z": 3.0}) == pytest.approx({"X": 1.0, "Y": 2.0, "Z": 3.0})
        assert be.last_round_trips == 1
        back = be.write_offsets({"X": 2000.0, "Y": 2.5, "Z": 3.5})      # 2 mm: above what the CNC takes
        assert back["X"] is None and back["Y"] == pytest.approx(2.5) and back["Z"] == pytest.approx(3.5)
        assert "BadOutOfRange" in be.last_error and "axis X" in be.last_error
        assert emulator.applied_um() == pytest.approx({"X": 1.0, "Y": 2.5, "Z": 3.5})
        assert be.connected and be.connections == 1
    finally:
        be.close()


class _ReorderingServer:
    """A uaclient whose server answers the pipelined read before it applies the write (OPC UA
    allows it), or never applies it (``applies=False``)."""

    def __init__(self, held: float, applies: bool = True):
        self.held, self.applies, self.reads = held, applies, 0

    async def write_attributes(self, nodeids, dvs, attr):
        from asyncua import ua
        await asyncio.sleep(0)              # the read is answered first
        if self.applies:
            self.held = dvs[0].Value.Value
        return [ua.StatusCode() for _ in nodeids]

    async def read_attributes(self, nodeids, attr):
        from asyncua import ua
        self.reads += 1
        return [ua.DataValue(ua.Variant(self.held, ua.VariantType.Double)) for _ in nodeids]


@pytest.mark.parametrize("applies", [True, False])
def test_a_read_answered_before_the_write_is_read_again_never_confirmed_on_status_alone(emulator, port, applies):
    from asyncua import ua
    be = backend(port)
    try:
        server = _ReorderingServer(held=0.001, applies=applies)
        client = type("FakeClient", (), {"uaclient": server})()
        written, back = be._io.run(be._write_and_read(client, [ua.NodeId(1, 2)], [0.004]), 5.0)
        assert written[0].is_good() and server.reads == 2 and be.last_round_trips == 2
        assert back[0].Value.Value == (0.004 if applies else 0.001)
    finally:
        be.close()


def test_the_health_check_reads_the_server_only_when_no_write_was_answered(emulator, port):
    """While writes are answered, their answers prove the session: no health-check read holds
    the write lock; with no write for a check period, the server's state is read again."""
    from asyncua import ua
    from asyncua.common.callback import CallbackType
    state_id = ua.NodeId(ua.ObjectIds.Server_ServerStatus_State)
    checks = []

    async def on_read(event, _dispatcher):
        checks.extend(r for r in event.request_params.NodesToRead if r.NodeId == state_id)
    emulator.emulator._server.subscribe_server_callback(CallbackType.PreRead, on_read)
    be = backend(port, inline=True, check_period_s=0.5)
    try:
        assert be.wait_connected(10), be.last_error
        wait_for(lambda: checks, 10, "a health check of an idle session", be)
        seen = len(checks)
        t_end = time.monotonic() + 1.5                    # three check periods of writes
        i = 0
        while time.monotonic() < t_end:
            i += 1
            assert be.write_offsets({"X": 0.001 * i}) == pytest.approx({"X": 0.001 * i})
            be.serve()
        # one check may have been on its way when the writes began
        assert len(checks) - seen <= 1, f"{len(checks) - seen} health-check reads among {i} answered writes"
        seen = len(checks)
        wait_for(lambda: len(checks) > seen, 10, "a health check once the writes stopped", be)
        assert be.connected and be.connections == 1
    finally:
        be.close()
