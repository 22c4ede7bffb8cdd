"""Self-signed certificates for OPC UA Basic256Sha256 (tests, benchmarks, demos), via `cryptography`.

For a real machine use certificates from the plant's PKI; these are for loopback trials.
The subject alternative name carries the application URI, as OPC UA requires.
"""
from __future__ import annotations

import datetime as dt
import pathlib
import socket

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID


def make_certificate(folder: pathlib.Path, name: str, application_uri: str,
                     server: bool, valid_days: float = 30.0) -> tuple[str, str]:
    """Write ``name.der`` (certificate) and ``name.pem`` (key, mode 600); return their paths.

    Valid from a day ago for ``valid_days`` from now (negative: already expired, for tests)."""
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "thermal-comp tests")])
    now = dt.datetime.now(dt.timezone.utc)
    usage = [ExtendedKeyUsageOID.SERVER_AUTH] if server else [ExtendedKeyUsageOID.CLIENT_AUTH]
    cert = (x509.CertificateBuilder()
            .subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(days=1)).not_valid_after(now + dt.timedelta(days=valid_days))
            .add_extension(x509.SubjectAlternativeName(
                [x509.UniformResourceIdentifier(application_uri), x509.DNSName("localhost"),
                 x509.DNSName(socket.gethostname())]), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True,
                                         key_encipherment=True, data_encipherment=True,
                                         key_agreement=False, key_cert_sign=False, crl_sign=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage(usage), critical=False)
            .sign(key, hashes.SHA256()))
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cert_path, key_path = folder / f"{name}.der", folder / f"{name}.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    key_path.touch(mode=0o600)            # readable by its owner only, before it holds the key
    key_path.chmod(0o600)
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.TraditionalOpenSSL,
                                           serialization.NoEncryption()))
    return str(cert_path), str(key_path)
