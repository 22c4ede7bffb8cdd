"""A trust list of OPC UA application certificates, checked on every secure connection.

Both ends use it: the bridge checks the CNC's server certificate, the CNC emulator checks
each client certificate. A certificate is trusted only if it is one of the listed ones
(compared by SHA-256 fingerprint, i.e. pinned; the plant's PKI would list its issued
certificates the same way) and valid now; anything else is refused with an OPC UA Bad
status (``BadCertificateUntrusted`` / ``BadCertificateTimeInvalid``), before any session.

The list is a folder of ``*.der`` / ``*.pem`` / ``*.crt`` files or a list of files.
"""
from __future__ import annotations

import datetime as dt
import logging
import pathlib
from typing import Iterable

from asyncua import ua
from asyncua.common.utils import ServiceError
from cryptography import x509
from cryptography.hazmat.primitives import hashes

log = logging.getLogger("cnc_bridge.trust_list")
_SUFFIXES = (".der", ".pem", ".crt", ".cer")


class TrustListError(ValueError):
    """A trust list cannot be read (the message names the file)."""


def load_certificate(path: str | pathlib.Path) -> x509.Certificate:
    p = pathlib.Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise TrustListError(f"certificate '{p}': cannot read: {exc.strerror}") from None
    if b"PRIVATE KEY-----" in data:
        raise TrustListError(f"certificate '{p}' holds a private key: a trust list holds "
                             f"certificates only (move the key out of that folder)")
    try:
        if b"-----BEGIN CERTIFICATE-----" in data:
            return x509.load_pem_x509_certificate(data)
        return x509.load_der_x509_certificate(data)
    except ValueError:
        raise TrustListError(f"certificate '{p}': not a DER or PEM X.509 certificate") from None


def fingerprint(cert: x509.Certificate) -> str:
    return cert.fingerprint(hashes.SHA256()).hex()


class TrustList:
    """Pinned certificates; an instance is an asyncua certificate validator (awaitable call)."""

    def __init__(self, certificates: Iterable[x509.Certificate], name: str = "trust list"):
        self.name = name
        self._trusted = {fingerprint(c): c for c in certificates}
        #: refusals so far: (subject, reason) - for tests and the status of a node
        self.refused: list[tuple[str, str]] = []

    @classmethod
    def from_paths(cls, paths: str | pathlib.Path | Iterable[str | pathlib.Path],
                   name: str = "trust list") -> "TrustList":
        """A folder (every certificate file in it) or one or more certificate files."""
        if isinstance(paths, (str, pathlib.Path)):
            paths = [paths]
        files: list[pathlib.Path] = []
        for p in map(pathlib.Path, paths):
            if p.is_dir():
                files += sorted(f for f in p.iterdir() if f.suffix.lower() in _SUFFIXES)
            else:
                files.append(p)
        if not files:
            raise TrustListError(f"{name}: no certificate in {[str(p) for p in paths]}")
        return cls([load_certificate(f) for f in files], name)

    def __len__(self) -> int:
        return len(self._trusted)

    def check(self, cert: x509.Certificate, now: dt.datetime | None = None) -> None:
        """Raise ServiceError(Bad...) unless ``cert`` is listed and valid at ``now``."""
        now = now or dt.datetime.now(dt.timezone.utc)
        subject = cert.subject.rfc4514_string()
        if fingerprint(cert) not in self._trusted:
            self._refuse(subject, "not in the trust list", ua.StatusCodes.BadCertificateUntrusted)
        if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
            self._refuse(subject, "expired or not yet valid", ua.StatusCodes.BadCertificateTimeInvalid)

    def _refuse(self, subject: str, reason: str, code: int) -> None:
        self.refused.append((subject, reason))
        log.warning("%s: refused certificate %s: %s", self.name, subject, reason)
        raise ServiceError(code)

    async def __call__(self, cert: x509.Certificate, app_description=None) -> None:
        self.check(cert)
