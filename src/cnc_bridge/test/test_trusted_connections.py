"""The bridge against an attacker and a clumsy operator: trust lists, logins, values a CNC refuses,
held offsets with compensation off, credentials that must not leak."""
from __future__ import annotations

import asyncio
import logging
import math

import pytest

from cnc_bridge.certificates import make_certificate
from cnc_bridge.cnc_emulator import (CncEmulatorThread, EmulatorConfig, EmulatorState,
                                     compensation_node_id)
from cnc_bridge.cnc_emulator.access import LoginBackoff, SessionGate
from cnc_bridge.credentials import (ENV_PASSWORD, ENV_USER, CredentialsError, load_credentials)
from cnc_bridge.opcua_config import OpcUaConfig, OpcUaConfigError

from test_opcua_backend import backend, endpoint, offset_writes, port, wait_for  # noqa: F401

logging.getLogger("asyncua").setLevel(logging.ERROR)


@pytest.fixture
def certs(tmp_path):
    server = make_certificate(tmp_path, "cnc", "urn:thermal-comp:cnc-emulator:server", server=True)
    client = make_certificate(tmp_path, "bridge", "urn:thermal-comp:cnc-bridge", server=False)
    stranger = make_certificate(tmp_path, "stranger", "urn:thermal-comp:cnc-bridge", server=False)
    rogue = make_certificate(tmp_path, "rogue", "urn:thermal-comp:cnc-emulator:server", server=True)
    return {"server": server, "client": client, "stranger": stranger, "rogue": rogue}


def secure_emulator(port, certs, **kw):
    return CncEmulatorThread(EmulatorConfig(
        port=port, certificate=certs["server"][0], private_key=certs["server"][1],
        security="required", user="cnc", password="pw", client_trust=(certs["client"][0],),
        **kw)).start()


def test_unknown_client_certificate_is_rejected(port, certs):
    emu = secure_emulator(port, certs)
    try:
        stranger = backend(port, user="cnc", password="pw", certificate=certs["stranger"][0],
                           private_key=certs["stranger"][1], security_required=True,
                           server_trust=(certs["server"][0],))
        try:
            wait_for(lambda: "BadCertificateUntrusted" in stranger.last_error, 20, "the refusal")
            assert not stranger.connected
            assert stranger.write_offsets({"X": 1.0}) == {"X": None}
        finally:
            stranger.close()
        assert emu.emulator.trust.refused and "stranger" in emu.emulator.trust.refused[0][0]
        assert offset_writes(emu, "X") == []
        trusted = backend(port, user="cnc", password="pw", certificate=certs["client"][0],
                          private_key=certs["client"][1], security_required=True,
                          server_trust=(certs["server"][0],))
        try:
            assert trusted.wait_connected(15), trusted.last_error
        finally:
            trusted.close()
    finally:
        emu.close()


def test_the_bridge_refuses_a_server_certificate_not_in_its_trust_list(port, certs):
    emu = secure_emulator(port, certs)
    try:
        be = backend(port, user="cnc", password="pw", certificate=certs["client"][0],
                     private_key=certs["client"][1], security_required=True,
                     server_trust=(certs["rogue"][0],))      # trusts another server only
        try:
            wait_for(lambda: "BadCertificateUntrusted" in be.last_error, 20, "the refusal")
            assert not be.connected
        finally:
            be.close()
        assert offset_writes(emu, "X") == []
    finally:
        emu.close()


def test_security_on_needs_a_user_and_trust_lists(certs):
    cert, key = certs["client"]
    with pytest.raises(OpcUaConfigError, match="user and password"):
        OpcUaConfig(endpoint="opc.tcp://127.0.0.1:1/x", certificate=cert, private_key=key,
                    security_required=True, server_trust=(certs["server"][0],))
    with pytest.raises(OpcUaConfigError, match="trust list"):
        OpcUaConfig(endpoint="opc.tcp://127.0.0.1:1/x", certificate=cert, private_key=key,
                    security_required=True, user="cnc", password="pw")
    server_cert, server_key = certs["server"]
    with pytest.raises(ValueError, match="anonymous sessions are refused"):
        EmulatorConfig(certificate=server_cert, private_key=server_key, security="required",
                       client_trust=(cert,))
    with pytest.raises(ValueError, match="trust list of client certificates"):
        EmulatorConfig(certificate=server_cert, private_key=server_key, security="required",
                       user="cnc", password="pw")


def test_login_backoff_doubles_per_client_and_resets_on_success():
    now = [0.0]
    gate = SessionGate("cnc", "s3cret", False, LoginBackoff(0.5, 8.0, clock=lambda: now[0]))
    a = b"certificate-a"
    key = gate.client_key("cnc", a)
    assert gate.get_user(None, "cnc", "wrong", a) is None           # 1st failure: 0.5 s
    assert gate.get_user(None, "cnc", "s3cret", a) is None          # right, but within back-off
    gate._peer = "192.0.2.7"                                        # another address is not held
    assert gate.get_user(None, "cnc", "s3cret", a) is not None
    gate._peer = "unknown-address"
    waits = []
    for _ in range(6):
        now[0] += gate.backoff.locked_for(key)
        waits.append(gate.backoff.locked_for(key))
        assert gate.get_user(None, "cnc", "wrong", a) is None
        waits.append(gate.backoff.locked_for(key))
    assert waits[1::2] == [1.0, 2.0, 4.0, 8.0, 8.0, 8.0]            # doubled, capped
    assert gate.backoff.refused_in_backoff == 1
    now[0] += 8.0
    assert gate.get_user(None, "cnc", "s3cret", a) is not None
    assert gate.backoff.locked_for(key) == 0.0


def test_twenty_wrong_passwords_are_slowed_down(port):
    """Wrong passwords are not tried at full speed: with the back-off most of 20 are
    refused without a password check; the count is printed, not asserted as a speed."""
    emu = CncEmulatorThread(EmulatorConfig(port=port, user="cnc", password="s3cret")).start()
    from asyncua import Client

    async def attempts(n):
        refused = 0
        for _ in range(n):
            c = Client(endpoint(port), timeout=2)
            c.set_user("cnc")
            c.set_password("wrong")
            try:
                await c.connect()
                await c.disconnect()
            except Exception:
                refused += 1
        return refused
    try:
        assert asyncio.run(attempts(20)) == 20
        gate = emu.emulator.gate
        print(f"20 wrong logins: {gate.backoff.refused_in_backoff} refused within the back-off")
        assert gate.backoff.refused_in_backoff >= 1
        # keyed by the client's address and the user it asks for
        assert list(gate.backoff._failures) == ["127.0.0.1/user=cnc"]
    finally:
        emu.close()


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, 1e9, 1.5])
def test_the_cnc_refuses_offsets_it_would_not_take(port, value):
    from asyncua import Client, ua
    emu = CncEmulatorThread(EmulatorConfig(port=port)).start()

    async def write():
        async with Client(endpoint(port)) as c:
            node = c.get_node(compensation_node_id("X", "SD43900"))
            with pytest.raises(ua.UaStatusCodeError, match="BadOutOfRange"):
                await node.write_value(ua.DataValue(ua.Variant(value, ua.VariantType.Double)))
            await node.write_value(ua.DataValue(ua.Variant(0.002, ua.VariantType.Double)))
            return await node.read_value()
    try:
        assert asyncio.run(write()) == 0.002                 # a sane value is still taken
        assert emu.applied_um()["X"] == 0.0                  # MD32750 still 0: not applied
        [(_, refused, why)] = emu.emulator.refused_writes
        assert (math.isnan(refused) if math.isnan(value) else refused == value), why
        assert all(math.isfinite(v) and abs(v) <= 1.0 for _, v in emu.write_log)
    finally:
        emu.close()


def test_held_offset_with_compensation_off_counts_as_zero_and_connecting_never_writes(port):
    """The CNC held X = -5 mm with compensation off; the first write of the bridge
    must start from zero (no 5 mm step), and nothing is written before that write."""
    state = EmulatorState(compensation={"X": {"SD43900": -5.0, "SD43910": 0.0, "SD43920": 0.0,
                                              "MD32750": 0}})
    emu = CncEmulatorThread(EmulatorConfig(port=port, compensation_axes=("X",),
                                           offset_limit_mm=10.0))
    emu.start(state)
    from cnc_bridge.opcua_config import default_node_map
    be = backend(port, node_map=default_node_map(("X",), position_axes=()))
    try:
        assert be.wait_connected(10), be.last_error
        assert be.held_state() == {"X": (pytest.approx(-5000.0), False)}
        assert be.held_offsets() == {"X": 0.0}
        assert emu.write_log == [], "connecting never writes"
        assert be.write_offsets({"X": 0.5}) == {"X": pytest.approx(0.5)}
        assert emu.applied_um()["X"] == pytest.approx(0.5)
        x_offsets = offset_writes(emu, "X")
        assert x_offsets == [pytest.approx(0.0), pytest.approx(0.0005)]   # 0 before enable, then 0.5 um
    finally:
        be.close()
        emu.close()


def test_credentials_file_must_be_private(tmp_path):
    f = tmp_path / "creds.yaml"
    f.write_text("user: cnc\npassword: s3cret\n")
    f.chmod(0o644)
    with pytest.raises(CredentialsError, match=r"readable by group or others \(mode 0644\)"):
        load_credentials(f)
    f.chmod(0o600)
    creds = load_credentials(f)
    assert (creds.user, creds.password) == ("cnc", "s3cret") and "s3cret" not in repr(creds)
    f.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(CredentialsError, match="not a YAML text file"):
        load_credentials(f)
    assert load_credentials(None, {ENV_USER: "op", ENV_PASSWORD: "x"}).user == "op"
    with pytest.raises(CredentialsError, match="together"):
        load_credentials(None, {ENV_USER: "op"})


def test_trust_list_refuses_unknown_and_expired_certificates(tmp_path):
    from asyncua.common.utils import ServiceError
    from asyncua import ua

    from cnc_bridge.trust_list import TrustList, TrustListError, load_certificate
    import shutil
    good = make_certificate(tmp_path / "keys", "bridge", "urn:thermal-comp:cnc-bridge", server=False)[0]
    with pytest.raises(TrustListError, match="holds a private key"):
        TrustList.from_paths(tmp_path / "keys")                  # the key lies beside it
    (tmp_path / "a").mkdir()
    good = shutil.copy(good, tmp_path / "a")
    old = make_certificate(tmp_path / "b", "old", "urn:thermal-comp:cnc-bridge", server=False,
                           valid_days=-0.5)[0]
    other = make_certificate(tmp_path / "c", "other", "urn:thermal-comp:cnc-bridge", server=False)[0]
    trust = TrustList.from_paths([tmp_path / "a", old])     # a folder and a file
    assert len(trust) == 2
    trust.check(load_certificate(good))
    with pytest.raises(ServiceError) as info:
        trust.check(load_certificate(old))
    assert info.value.code == ua.StatusCodes.BadCertificateTimeInvalid
    with pytest.raises(ServiceError) as info:
        trust.check(load_certificate(other))
    assert info.value.code == ua.StatusCodes.BadCertificateUntrusted
    assert [r[1] for r in trust.refused] == ["expired or not yet valid", "not in the trust list"]
    (tmp_path / "junk.der").write_bytes(b"not a certificate")
    with pytest.raises(TrustListError, match="junk.der.*not a DER or PEM"):
        TrustList.from_paths(tmp_path / "junk.der")
    with pytest.raises(TrustListError, match="no certificate"):
        TrustList.from_paths([])
