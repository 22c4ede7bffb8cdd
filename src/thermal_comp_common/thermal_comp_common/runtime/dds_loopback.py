"""A cell that asks for LOCALHOST discovery gets DDS on the loopback interface only.

``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` alone limits whom Fast DDS (the only RMW available
here) discovers, not where it listens: its unicast listeners bind 0.0.0.0 and it keeps send
sockets on every interface. A Fast DDS XML profile whose only transports are UDPv4 restricted
to 127.0.0.1 (``interfaceWhiteList``) and shared memory binds every socket to loopback; with it
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
    <transport_descriptor>
      <transport_id>local_shm</transport_id>
      <type>SHM</type>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="thermal_comp_loopback" is_default_profile="true">
    <rtps>
      <userTransports>
        <transport_id>loopback_udp</transport_id>
        <transport_id>local_shm</transport_id>
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
