"""A process of a cell uses UDP only unless told otherwise; one that asks for LOCALHOST discovery
opens no DDS socket outside the loopback interface, and still talks to an in-process node that
only set LOCALHOST."""
import os
import pathlib
import subprocess
import sys
import time

import pytest

from thermal_comp_common.runtime.dds_transport import (PROFILE_NAME, PROFILES_ENV, RANGE_ENV, TRANSPORTS_ENV,
                                                       cell_process_env, loopback_env, restart_safe_env)

CHILD = """
import sys, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("loopback_child")
pub = node.create_publisher(String, "loopback_chat", 10)
print("ready", flush=True)
while rclpy.ok():
    pub.publish(String(data="hi"))
    rclpy.spin_once(node, timeout_sec=0.1)
"""


def test_env_only_changes_a_localhost_process_without_its_own_profile(tmp_path):
    assert loopback_env({RANGE_ENV: "SUBNET"}, tmp_path) == {RANGE_ENV: "SUBNET"}
    own = {RANGE_ENV: "LOCALHOST", PROFILES_ENV: "/etc/mine.xml"}
    assert loopback_env(own, tmp_path) == own
    env = loopback_env({RANGE_ENV: "LOCALHOST", "X": "1"}, tmp_path)
    assert env[PROFILES_ENV] == str(tmp_path / PROFILE_NAME) and env["X"] == "1"
    assert "<address>127.0.0.1</address>" in pathlib.Path(env[PROFILES_ENV]).read_text()


def test_a_cell_process_uses_udp_only_unless_it_names_a_transport_or_a_profile(tmp_path):
    assert restart_safe_env({"X": "1"}) == {"X": "1", TRANSPORTS_ENV: "UDPv4"}
    assert restart_safe_env({TRANSPORTS_ENV: "SHM"}) == {TRANSPORTS_ENV: "SHM"}
    assert restart_safe_env({PROFILES_ENV: "/etc/mine.xml"}) == {PROFILES_ENV: "/etc/mine.xml"}
    # the loopback profile names its own transports: UDP on lo, no shared memory
    env = cell_process_env({RANGE_ENV: "LOCALHOST"}, tmp_path)
    assert env[TRANSPORTS_ENV] == "UDPv4"
    assert "SHM" not in pathlib.Path(env[PROFILES_ENV]).read_text()
    assert cell_process_env({}, tmp_path) == {TRANSPORTS_ENV: "UDPv4"}


def _udp_local_addresses(pid: int) -> list[str]:
    """Local IPv4 addresses of the UDP sockets process ``pid`` holds (from /proc)."""
    inodes = set()
    for fd in pathlib.Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for line in pathlib.Path(f"/proc/{pid}/net/udp").read_text().splitlines()[1:]:
        cols = line.split()
        if cols[9] in inodes:
            ip_hex = cols[1].split(":")[0]
            found.append(".".join(str(int(ip_hex[i:i + 2], 16)) for i in (6, 4, 2, 0)))
    return found


@pytest.mark.ros
def test_every_dds_socket_is_on_loopback_and_a_localhost_node_hears_it(tmp_path):
    import rclpy                                  # ros tests only: the fast lane needs no rclpy
    from std_msgs.msg import String               # same reason
    env = loopback_env({**os.environ, RANGE_ENV: "LOCALHOST"}, tmp_path)
    child = subprocess.Popen([sys.executable, "-c", CHILD], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        context = rclpy.Context()
        rclpy.init(context=context)
        node = rclpy.create_node("loopback_listener", context=context)
        got = []
        node.create_subscription(String, "loopback_chat", lambda m: got.append(m.data), 10)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 30.0          # a bound on discovery, not a synchronisation
        while not got and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.2)
        addresses = _udp_local_addresses(child.pid)
        node.destroy_node()
        rclpy.shutdown(context=context)
        assert got, "a LOCALHOST node did not hear the loopback-only process within 30 s"
        assert addresses and all(a.startswith("127.") or a.startswith("239.") for a in addresses), addresses
    finally:
        child.terminate()
        child.wait(timeout=10)
