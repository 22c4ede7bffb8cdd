"""The DDS transports of a cell's processes: UDP only, and on loopback where LOCALHOST is asked.

Fast DDS's shared-memory transport does not survive a participant killed with SIGKILL (the OOM
killer, a watchdog, ``kill -9``): its ports and ring buffers live in /dev/shm, and a restarted
process can stay deaf to the survivors (known upstream; docs/distributed.md). A launcher that
restarts crashed nodes therefore gives every process UDPv4 only (``FASTDDS_BUILTIN_TRANSPORTS``),
which keeps no state between processes (the cell's messages are a few kB). A transport or
profile the user set is left alone.

A cell that asks for LOCALHOST discovery gets DDS on the loopback interface only:

``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` alone limits whom Fast DDS (the only RMW available
here) discovers, not where it listens: its unicast listeners bind 0.0.0.0 and it keeps send
sockets on every interface. A Fast DDS XML profile whose only transports are UDPv4 restricted
to 127.0.0.1 (``interfaceWhiteList``) binds every socket to loopback; with it
the range is SUBNET on that one interface (multicast discovery on ``lo``), which still reaches
LOCALHOST participants without the profile (both directions checked). A profile the user set
(``FASTRTPS_DEFAULT_PROFILES_FILE``) is left alone. docs/distributed.md, section "Loopback".
"""
from __future__ import annotations

import pathlib
from typing import Mapping

RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
#: Fast DDS 2.x (ROS 2 Jazzy) reads its default XML profiles from this file
PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: Fast DDS (2.13 on) builds its default transports from this variable
TRANSPORTS_ENV = "FASTDDS_BUILTIN_TRANSPORTS"
PROFILE_NAME = "fastdds_loopback.xml"

PROFILE_XML = """<?xml version="1.0" encoding="UTF-8" ?>
<!-- thermal-comp: DDS on the loopback interface only (a cell that asks for LOCALHOST) -->
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>loopback_udp</transport_id>
      <type>UDPv4</type>
      <interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="thermal_comp_loopback" is_default_profile="true">
    <rtps>
      <userTransports>
        <transport_id>loopback_udp</transport_id>
      </userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
</profiles>
"""


def wants_loopback(env: Mapping[str, str]) -> bool:
    """The process environment ``env`` asks for LOCALHOST discovery and sets no profile of its own."""
    return env.get(RANGE_ENV, "").strip().upper() == "LOCALHOST" and not env.get(PROFILES_ENV)


def loopback_env(env: Mapping[str, str], directory: str | pathlib.Path) -> dict[str, str]:
    """``env`` for a process of a cell: where it asks for LOCALHOST (and names no profile), the
    loopback profile (written once into ``directory``) and the SUBNET range it confines to ``lo``."""
    out = dict(env)
    if not wants_loopback(out):
        return out
    path = pathlib.Path(directory) / PROFILE_NAME
    if not path.is_file() or path.read_text() != PROFILE_XML:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(PROFILE_XML)
    out[PROFILES_ENV] = str(path)
    out[RANGE_ENV] = "SUBNET"
    return out


def restart_safe_env(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` with UDPv4 as the only DDS transport, unless it names a transport or a profile."""
    out = dict(env)
    if not out.get(TRANSPORTS_ENV) and not out.get(PROFILES_ENV):
        out[TRANSPORTS_ENV] = "UDPv4"
    return out


def cell_process_env(env: Mapping[str, str], directory: str | pathlib.Path) -> dict[str, str]:
    """The DDS environment of one process of a cell: UDP only (the loopback profile, where asked,
    names UDP on lo as its only transport and so overrides the built-in choice)."""
    return loopback_env(restart_safe_env(env), directory)
