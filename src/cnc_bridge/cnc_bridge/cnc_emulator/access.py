"""Who may open a session on the emulated CNC, and how fast wrong passwords may be tried.

:class:`SessionGate` is asyncua's user manager (called on every ActivateSession):

* with security required, a session on a channel without a client certificate (security
  policy None) is refused here, server-side: asyncua would otherwise let a client that
  ignores the endpoint list activate a session over an unsecured channel;
* with a trust list, the certificate of the session's channel is checked against it here
  too: asyncua checks only the certificate a client names in CreateSession, and a client
  may leave that empty while securing its channel with another one;
* with a user name/password configured only that user gets in (anonymous sessions are
  refused); the password is compared in constant time;
* :class:`LoginBackoff`: after a failed login the same client is refused without even
  checking the password for a delay that doubles with each further failure (``base_s``,
  ``2 base_s`` ... up to ``max_s``); a success resets it. A client is its network address
  and the user name it asks for (:meth:`SessionGate.client_key`): a certificate does not make
  a new client, since anyone can make a fresh self-signed one per guess, except a certificate
  on the trust list (checked above, so a guesser cannot mint one), which keeps the bridge's own
  session from being held back by a guesser on its host. asyncua does not pass the peer to
  the user manager, so :meth:`SessionGate.attach` wraps the server's session creation to note
  the address of the session being activated (activation is synchronous, so no other session
  can interleave).
"""
from __future__ import annotations

import hashlib
import hmac
import logging
import time
from typing import Callable

from asyncua.crypto.permission_rules import User, UserRole
from asyncua.ua.uaerrors import UaError
from cryptography import x509

log = logging.getLogger("cnc_emulator")


def open_access_warning(security: str, has_trust_list: bool) -> str | None:
    """The one line an operator must see when the CNC is open to anyone, or None."""
    if security == "optional" and not has_trust_list:
        return ("cnc-emulator: WARNING: --security optional without --client-trust: unsecured "
                "connections and any client certificate are accepted; a production cell needs "
                "--security required with a client trust list")
    return None


class LoginBackoff:
    """Exponential back-off per client key; ``clock`` is injectable for deterministic tests."""

    def __init__(self, base_s: float = 0.5, max_s: float = 60.0,
                 clock: Callable[[], float] = time.monotonic):
        if not (base_s > 0 and max_s >= base_s):
            raise ValueError(f"login back-off: need 0 < base_s <= max_s, got {base_s!r}, {max_s!r}")
        self.base_s, self.max_s, self.clock = base_s, max_s, clock
        self._failures: dict[str, int] = {}
        self._locked_until: dict[str, float] = {}
        self.refused_in_backoff = 0

    def locked_for(self, key: str) -> float:
        """Seconds this client must still wait (0 = may try)."""
        return max(0.0, self._locked_until.get(key, 0.0) - self.clock())

    def failed(self, key: str) -> float:
        n = self._failures.get(key, 0) + 1
        self._failures[key] = n
        delay = min(self.base_s * 2 ** (n - 1), self.max_s)
        self._locked_until[key] = self.clock() + delay
        return delay

    def succeeded(self, key: str) -> None:
        self._failures.pop(key, None)
        self._locked_until.pop(key, None)


class SessionGate:
    """asyncua user manager; see the module docstring. ``trust`` is the client trust list
    (a :class:`cnc_bridge.trust_list.TrustList`, or None when there is none)."""

    def __init__(self, user: str | None, password: str | None, security_required: bool,
                 backoff: LoginBackoff | None = None, trust=None):
        self._user, self._password = user, password
        self._security_required = security_required
        self.backoff = backoff or LoginBackoff()
        self.trust = trust
        self._peer = "unknown-address"

    def attach(self, iserver) -> None:
        """Note each session's peer address when it is activated (see the module docstring)."""
        create = iserver.create_session
        gate = self

        def create_session(name, *args, **kwargs):
            session = create(name, *args, **kwargs)
            activate = session.activate_session
            host = name[0] if isinstance(name, tuple) and name else str(name)

            def activate_session(*a, **kw):
                gate._peer = host
                try:
                    return activate(*a, **kw)
                finally:
                    gate._peer = "unknown-address"
            session.activate_session = activate_session
            return session
        iserver.create_session = create_session

    def client_key(self, username, certificate) -> str:
        """The back-off's client: address and user name, plus the certificate only when a
        trust list vouches for it (see the module docstring)."""
        key = f"{self._peer}/user={username!s}"
        if certificate and self.trust is not None:
            key += "/" + hashlib.sha256(certificate).hexdigest()[:16]
        return key

    def _untrusted(self, certificate) -> bool:
        """True (and logged by the trust list) if a trust list is set and ``certificate`` is
        not a valid certificate on it."""
        if self.trust is None or not certificate:
            return False
        try:
            self.trust.check(x509.load_der_x509_certificate(bytes(certificate)))
        except (UaError, ValueError):
            return True
        return False

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if self._security_required and not certificate:
            log.warning("refused a session on an unsecured channel (security required)")
            return None
        if self._untrusted(certificate):
            return None
        if self._user is None:
            return User(role=UserRole.User)
        key = self.client_key(username, certificate)
        wait = self.backoff.locked_for(key)
        if wait > 0:
            self.backoff.refused_in_backoff += 1
            log.warning("refused session for user %r from client %s: %.1f s of login back-off left",
                        username, key, wait)
            return None
        given = password if isinstance(password, bytes) else str(password or "").encode()
        ok = (username == self._user and password is not None and
              hmac.compare_digest(given, str(self._password).encode()))
        if ok:
            self.backoff.succeeded(key)
            return User(role=UserRole.User, name=username)
        delay = self.backoff.failed(key)
        log.warning("refused session for user %r from client %s; next try in %.1f s",
                    username, key, delay)
        return None
