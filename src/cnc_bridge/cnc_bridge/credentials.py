"""OPC UA credentials (user, password, private key) from a protected file or the environment.

Secrets never travel as ROS parameters (anyone on the domain can read those with
``ros2 param get``) nor on a command line (``ps`` shows it). They come from:

* a YAML file (``user: ..., password: ..., private_key: /path/key.pem``) that only its owner
  may read: a file with any group or world permission bit is refused with one error naming
  the file and its mode (like ssh does for keys); the same holds for the private key file;
* or, when no file is given, the environment: ``THERMAL_COMP_OPCUA_USER``,
  ``THERMAL_COMP_OPCUA_PASSWORD``, ``THERMAL_COMP_OPCUA_PRIVATE_KEY`` (a path).
"""
from __future__ import annotations

import os
import pathlib
import stat
from dataclasses import dataclass
from typing import Mapping

import yaml

ENV_USER = "THERMAL_COMP_OPCUA_USER"
ENV_PASSWORD = "THERMAL_COMP_OPCUA_PASSWORD"
ENV_PRIVATE_KEY = "THERMAL_COMP_OPCUA_PRIVATE_KEY"
_KEYS = {"user", "password", "private_key"}
#: names that must never be parameters or command-line options of a node
SECRET_NAMES = ("password", "user", "private_key")


class CredentialsError(ValueError):
    """Credentials are missing, malformed or too widely readable (the message names the file)."""


@dataclass(frozen=True)
class Credentials:
    user: str | None = None
    password: str | None = None
    private_key: str | None = None     # path of the PEM key of the client certificate

    def __repr__(self) -> str:          # never print a password by accident
        return (f"Credentials(user={self.user!r}, password={'***' if self.password else None}, "
                f"private_key={self.private_key!r})")


def check_private_file(path: str | os.PathLike, what: str) -> pathlib.Path:
    """Refuse a file that is not a regular file or that group/others may access."""
    p = pathlib.Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise CredentialsError(f"{what} '{p}': cannot read: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise CredentialsError(f"{what} '{p}': not a regular file")
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o077:
        raise CredentialsError(f"{what} '{p}': readable by group or others (mode {mode:04o}); "
                               f"run: chmod 600 {p}")
    return p


def load_credentials(path: str | os.PathLike | None = None,
                     environ: Mapping[str, str] | None = None) -> Credentials:
    """Credentials from ``path`` (if given) or the environment; see the module docstring."""
    if path:
        p = check_private_file(path, "credentials file")
        try:
            data = yaml.safe_load(p.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, yaml.YAMLError) as exc:
            raise CredentialsError(f"credentials file '{p}': not a YAML text file "
                                   f"({type(exc).__name__})") from None
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise CredentialsError(f"credentials file '{p}': expected a mapping with keys "
                                   f"{sorted(_KEYS)}")
        unknown = set(data) - _KEYS
        if unknown:
            raise CredentialsError(f"credentials file '{p}': unknown key {sorted(unknown)[0]!r} "
                                   f"(allowed: {sorted(_KEYS)})")
        for k, v in data.items():
            if v is not None and not isinstance(v, str):
                raise CredentialsError(f"credentials file '{p}': '{k}' must be a string")
        creds = Credentials(data.get("user") or None, data.get("password"), data.get("private_key") or None)
    else:
        env = os.environ if environ is None else environ
        creds = Credentials(env.get(ENV_USER) or None, env.get(ENV_PASSWORD),
                            env.get(ENV_PRIVATE_KEY) or None)
    if (creds.user is None) != (creds.password is None):
        raise CredentialsError("credentials: user and password must be given together "
                               f"({'file ' + str(path) if path else 'environment ' + ENV_USER + '/' + ENV_PASSWORD})")
    if creds.private_key:
        check_private_file(creds.private_key, "private key")
    return creds
