"""OPC UA backend settings: the node-id map of each axis (:class:`AxisNodes`, the SINUMERIK-like
default of :func:`default_node_map`, a YAML map read by :func:`load_node_map`) and the client's
settings (:class:`OpcUaConfig`), each checked on construction so that a bad setting is one
:class:`OpcUaConfigError` naming it before any connection. The client is :mod:`cnc_bridge.opcua_backend`.
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field
from typing import Mapping

from asyncua import ua
import yaml

from thermal_comp_common.runtime.production import PRODUCTION_ENV, production_mode


class OpcUaConfigError(ValueError):
    """The OPC UA backend's settings are inconsistent (the message names the setting)."""


@dataclass(frozen=True)
class AxisNodes:
    """Node ids of one axis (``None`` = the CNC has no such node)."""

    offset: str
    slope: str | None = None
    ref_position: str | None = None
    enable: str | None = None
    position: str | None = None


def default_node_map(axes=("X", "Y", "Z"), position_axes=("X", "Y", "Z", "B", "C"),
                     ns: int = 2) -> dict[str, AxisNodes]:
    """SINUMERIK-like default layout (that of the CNC emulator)."""
    out = {}
    for a in axes:
        comp = f"ns={ns};s=TempComp.{a}."
        out[a] = AxisNodes(offset=comp + "SD43900", slope=comp + "SD43910",
                           ref_position=comp + "SD43920", enable=comp + "MD32750",
                           position=f"ns={ns};s=Axis.{a}.Position" if a in position_axes else None)
    for a in position_axes:
        if a not in out:          # rotary axes: read positions only (B for eq. 6.3-6.5)
            out[a] = AxisNodes(offset="", position=f"ns={ns};s=Axis.{a}.Position")
    return out


def load_node_map(path: str | pathlib.Path) -> tuple[dict[str, AxisNodes], float]:
    """Read a node-id map YAML; returns (axis -> nodes, node units per um).

    Format::

        offset_units_per_um: 0.001      # SD43900 holds mm
        axes:
          X: {offset: "ns=2;s=TempComp.X.SD43900", slope: "...", ref_position: "...",
              enable: "...", position: "ns=2;s=Axis.X.Position"}
          B: {position: "ns=2;s=Axis.B.Position"}
    """
    p = pathlib.Path(path)
    try:
        spec = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise OpcUaConfigError(f"node map '{p}': {exc}") from exc
    if not isinstance(spec, dict) or not isinstance(spec.get("axes"), dict) or not spec["axes"]:
        raise OpcUaConfigError(f"node map '{p}': needs a non-empty mapping 'axes'")
    scale = spec.get("offset_units_per_um", 0.001)
    if not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise OpcUaConfigError(f"node map '{p}': 'offset_units_per_um' must be > 0, got {scale!r}")
    out = {}
    for axis, nodes in spec["axes"].items():
        if not isinstance(nodes, dict):
            raise OpcUaConfigError(f"node map '{p}': axes.{axis} must be a mapping, got {nodes!r}")
        unknown = set(nodes) - {"offset", "slope", "ref_position", "enable", "position"}
        if unknown:
            raise OpcUaConfigError(f"node map '{p}': axes.{axis}: unknown key(s) {sorted(unknown)}")
        for k, v in nodes.items():
            try:
                ua.NodeId.from_string(v)
            except Exception:
                raise OpcUaConfigError(f"node map '{p}': axes.{axis}.{k}: bad node id {v!r}") from None
        out[str(axis)] = AxisNodes(offset=nodes.get("offset", ""), slope=nodes.get("slope"),
                                   ref_position=nodes.get("ref_position"),
                                   enable=nodes.get("enable"), position=nodes.get("position"))
    return out, float(scale)


@dataclass(frozen=True)
class OpcUaConfig:
    endpoint: str
    node_map: Mapping[str, AxisNodes] = field(default_factory=default_node_map)
    offset_units_per_um: float = 0.001        # SD43900 is in mm
    user: str | None = None
    password: str | None = None
    certificate: str | None = None            # client certificate (DER/PEM)
    private_key: str | None = None            # its private key (PEM)
    server_certificate: str | None = None     # pin the server's certificate (optional)
    server_trust: tuple[str, ...] = ()        # trust list: folder(s) / files of server certificates
    security_required: bool = False
    application_uri: str = "urn:thermal-comp:cnc-bridge"
    timeout_s: float = 2.0                    # per request
    check_period_s: float = 0.5               # session health check
    reconnect_min_s: float = 0.1
    reconnect_max_s: float = 5.0
    readback_tolerance: float = 1e-9          # in node units

    def __post_init__(self):
        if not self.endpoint.startswith("opc.tcp://"):
            raise OpcUaConfigError(f"endpoint: must start with opc.tcp://, got {self.endpoint!r}")
        if bool(self.certificate) != bool(self.private_key):
            raise OpcUaConfigError("certificate and private_key must be given together")
        if production_mode() and not self.security_required:
            raise OpcUaConfigError(f"security_required: False in a production cell ({PRODUCTION_ENV}=1): "
                                   "refusing a connection without Sign&Encrypt and a login")
        if self.security_required and not self.certificate:
            raise OpcUaConfigError(
                "security_required: a client certificate and private key are needed for "
                "Basic256Sha256 Sign&Encrypt; refusing an insecure connection")
        if (self.user is None) != (self.password is None):
            raise OpcUaConfigError("user and password must be given together")
        if self.security_required and self.user is None:
            raise OpcUaConfigError("security_required: a user and password are needed "
                                   "(credentials file or environment); refusing an anonymous session")
        if self.security_required and not (self.server_trust or self.server_certificate):
            raise OpcUaConfigError("security_required: a trust list of server certificates "
                                   "(server_trust) or a pinned server_certificate is needed")
        for name in ("timeout_s", "check_period_s", "reconnect_min_s", "reconnect_max_s",
                     "offset_units_per_um"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise OpcUaConfigError(f"{name}: must be > 0, got {v!r}")
