"""The emulator's address space: node ids, and which written values a CNC accepts.

Node ids are ``ns=2;s=...`` (the emulator's namespace is registered first, so its index is
2). A real controller checks setting data before taking it: the offset SD43900 is bounded
by the machine data (here ``offset_limit_mm``), the slope and reference position must be
finite, the enable MD32750 is a small integer. A value outside that is answered with
``BadOutOfRange`` for that node and changes nothing (:func:`write_refusal`).
"""
from __future__ import annotations

import math
import socket

from asyncua import ua

from cnc_bridge.cnc_emulator.axes import DEFAULT_COMPENSATION_AXES, DEFAULT_POSITION_AXES  # noqa: F401 (exported here)

NAMESPACE_URI = "urn:thermal-comp:cnc-emulator"
ENDPOINT_PATH = "/thermal-comp/cnc"
COMPENSATION_NODES = ("SD43900", "SD43910", "SD43920", "MD32750")
UM_PER_MM = 1000.0
PROBE_OBJECT_ID = "ns=2;s=Probe"
PROBE_METHOD_ID = "ns=2;s=Probe.ProbeMove"
#: largest |SD43900| the emulated CNC accepts, mm (a real one: its machine data)
DEFAULT_OFFSET_LIMIT_MM = 1.0
#: largest |SD43910| slope, mm/mm, and |SD43920| reference position, mm
SLOPE_LIMIT = 1e-3
REF_POSITION_LIMIT_MM = 1e5
MD32750_VALUES = range(0, 4)


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` that is free right now (bind port 0, read it, close)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def position_node_id(axis: str, ns: int = 2) -> str:
    return f"ns={ns};s=Axis.{axis}.Position"


def compensation_node_id(axis: str, item: str, ns: int = 2) -> str:
    """``item`` is one of SD43900, SD43910, SD43920, MD32750, Applied."""
    return f"ns={ns};s=TempComp.{axis}.{item}"


def write_refusal(item: str, value, offset_limit_mm: float) -> str | None:
    """Why the CNC refuses ``value`` for compensation node ``item`` (None = accepted)."""
    if item == "MD32750":
        if isinstance(value, bool) or not isinstance(value, int) or value not in MD32750_VALUES:
            return f"MD32750 must be an integer in 0..{MD32750_VALUES[-1]}, got {value!r}"
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return f"{item} must be a finite number, got {value!r}"
    limit = {"SD43900": offset_limit_mm, "SD43910": SLOPE_LIMIT,
             "SD43920": REF_POSITION_LIMIT_MM}.get(item)
    if limit is not None and abs(value) > limit:
        return f"{item} = {value!r} is beyond the limit +-{limit:g}"
    return None


BAD_OUT_OF_RANGE = ua.StatusCode(ua.StatusCodes.BadOutOfRange)
