"""Who may open a session on the emulated CNC, and how fast wrong passwords may be tried.

:class:`SessionGate` is asyncua's user manager (called on every ActivateSession):

* with security required, a session on a channel without a client certificate (security
  policy None) is refused here, server-side: asyncua would otherwise let a client that
  ignores the endpoint list activate a session over an unsecured channel (the certificate
  itself was checked against the trust list when the session was created);
* with a user name/password configured only that user gets in (anonymous sessions are
  refused); the password is compared in constant time;
* :class:`LoginBackoff`: after a failed login the same client is refused without even
  checking the password for a delay that doubles with each further failure (``base_s``,
  ``2 base_s`` ... up to ``max_s``); a success resets it. A client is its network address
  together with its certificate (fingerprint, or "no-certificate"): asyncua does not pass
  the peer to the user manager, so :meth:`SessionGate.attach` wraps the server's session
  creation to note the address of the session being activated (activation is synchronous,
  so no other session can interleave).
"""
from __future__ import annotations

import hashlib
import hmac
import logging
import time
from typing import Callable

from asyncua.crypto.permission_rules import User, UserRole

log = logging.getLogger("cnc_emulator")


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
    """asyncua user manager; see the module docstring."""

    def __init__(self, user: str | None, password: str | None, security_required: bool,
                 backoff: LoginBackoff | None = None):
        self._user, self._password = user, password
        self._security_required = security_required
        self.backoff = backoff or LoginBackoff()
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

    def client_key(self, certificate) -> str:
        who = hashlib.sha256(certificate).hexdigest()[:16] if certificate else "no-certificate"
        return f"{self._peer}/{who}"

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if self._security_required and not certificate:
            log.warning("refused a session on an unsecured channel (security required)")
            return None
        if self._user is None:
            return User(role=UserRole.User)
        key = self.client_key(certificate)
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
