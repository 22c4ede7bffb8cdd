"""The CNC's login back-off cannot be side-stepped: a client is its address and the user it
asks for, whatever certificate it presents (only a certificate on the trust list is a client
of its own), and the certificate of the session's channel is checked against the trust list."""
from __future__ import annotations

import asyncio
import logging

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from cnc_bridge.certificates import make_certificate
from cnc_bridge.cnc_emulator import CncEmulatorThread, EmulatorConfig
from cnc_bridge.cnc_emulator.access import LoginBackoff, SessionGate, open_access_warning
from cnc_bridge.trust_list import TrustList

from test_opcua_backend import endpoint, port  # noqa: F401

logging.getLogger("asyncua").setLevel(logging.ERROR)


def _frozen_gate(trust=None) -> SessionGate:
    gate = SessionGate("cnc", "s3cret", False, LoginBackoff(0.5, 60.0, clock=lambda: 100.0), trust=trust)
    gate._peer = "203.0.113.5"          # what attach() notes for a session from that address
    return gate


def test_a_fresh_certificate_per_guess_is_still_the_same_client():
    gate = _frozen_gate()
    results = [gate.get_user(None, "cnc", f"guess-{i}", f"self-signed-{i}".encode()) for i in range(20)]
    assert results == [None] * 20
    # the first guess was checked; the 19 others were refused by the back-off unchecked
    assert gate.backoff.refused_in_backoff == 19
    assert list(gate.backoff._failures) == ["203.0.113.5/user=cnc"]
    # even the right password, with yet another certificate, waits out the back-off
    assert gate.get_user(None, "cnc", "s3cret", b"self-signed-20") is None
    # a guess without a certificate is the same client too
    assert gate.get_user(None, "cnc", "guess", None) is None
    assert gate.backoff.refused_in_backoff == 21


def test_a_trusted_certificate_is_its_own_client_and_an_untrusted_one_is_refused(tmp_path):
    bridge = make_certificate(tmp_path, "bridge", "urn:thermal-comp:cnc-bridge", server=False)
    stranger = make_certificate(tmp_path, "stranger", "urn:thermal-comp:cnc-bridge", server=False)
    trust = TrustList.from_paths(bridge[0], "client trust list")
    gate = _frozen_gate(trust)
    bridge_der = open(bridge[0], "rb").read()
    stranger_der = open(stranger[0], "rb").read()
    # a guesser on the bridge's host without a certificate is held back ...
    assert gate.get_user(None, "cnc", "guess", None) is None
    assert gate.get_user(None, "cnc", "guess", None) is None
    assert gate.backoff.refused_in_backoff == 1
    # ... and does not hold back the bridge, whose certificate no guesser can mint
    assert gate.get_user(None, "cnc", "s3cret", bridge_der) is not None
    # a channel secured with a certificate not on the list gets no session, right password or not
    assert gate.get_user(None, "cnc", "s3cret", stranger_der) is None
    assert [r[1] for r in trust.refused] == ["not in the trust list"]


def test_open_access_warning_only_without_a_trust_list():
    assert "WARNING" in open_access_warning("optional", False)
    assert open_access_warning("optional", True) is None
    assert open_access_warning("required", True) is None


def test_guesses_with_a_fresh_certificate_each_over_opc_ua(port, tmp_path):  # noqa: F811
    """The attack end to end: security optional, no client trust list, each guess on a channel
    secured with a new self-signed certificate: only the first is checked."""
    srv = make_certificate(tmp_path, "cnc", "urn:thermal-comp:cnc-emulator:server", server=True)
    n = 4
    clients = [make_certificate(tmp_path, f"guesser{i}", "urn:thermal-comp:cnc-bridge", server=False)
               for i in range(n)]
    # a back-off longer than the whole attack: every guess after the first falls inside it
    emu = CncEmulatorThread(EmulatorConfig(port=port, user="cnc", password="s3cret", certificate=srv[0],
                                           private_key=srv[1], login_backoff_s=(60.0, 60.0))).start()

    async def guess(cert):
        c = Client(endpoint(port), timeout=5)
        await c.set_security(SecurityPolicyBasic256Sha256, cert[0], cert[1], server_certificate=srv[0],
                             mode=ua.MessageSecurityMode.SignAndEncrypt)
        c.set_user("cnc")
        c.set_password("wrong")
        try:
            await c.connect()
        except Exception:
            return False
        await c.disconnect()
        return True

    async def attack():
        return [await guess(cert) for cert in clients]
    try:
        assert asyncio.run(attack()) == [False] * n
        gate = emu.emulator.gate
        assert gate.backoff.refused_in_backoff == n - 1
        assert list(gate.backoff._failures) == ["127.0.0.1/user=cnc"]
    finally:
        emu.close()
