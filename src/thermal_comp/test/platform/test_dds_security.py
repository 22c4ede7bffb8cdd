"""DDS security fails closed: with ROS_SECURITY_STRATEGY=Enforce a node whose enclave is
missing or invalid never starts unsecured (docs/security.md). With the wheels here Fast DDS
has no security plugins, so no secured topic can be exchanged at all; the message says so."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros]

SCRIPT = """
import rclpy
ctx = rclpy.context.Context()
try:
    rclpy.init(args=["x", "--ros-args", "--enclave", "/cell/bridge"], context=ctx)
    rclpy.create_node("bridge", namespace="/cell", context=ctx)
except Exception as exc:
    print("REFUSED", str(exc).replace(chr(10), " "))
else:
    print("STARTED")
"""


def _run(keystore, ros_domain_id):
    env = dict(os.environ, ROS_SECURITY_ENABLE="true", ROS_SECURITY_STRATEGY="Enforce",
               ROS_SECURITY_KEYSTORE=str(keystore), ROS_DOMAIN_ID=str(ros_domain_id))
    done = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True,
                          timeout=120)
    return done.stdout.strip().splitlines()[-1]


def test_enforced_security_without_an_enclave_refuses_to_start(tmp_path, ros_domain_id):
    line = _run(tmp_path / "no_keystore", ros_domain_id)
    assert line.startswith("REFUSED") and "enclaves/cell/bridge" in line


def test_enforced_security_with_an_invalid_enclave_refuses_to_start(tmp_path, ros_domain_id):
    enclave = tmp_path / "ks" / "enclaves" / "cell" / "bridge"
    enclave.mkdir(parents=True)
    for name in ("cert.pem", "key.pem", "identity_ca.cert.pem", "permissions_ca.cert.pem",
                 "governance.p7s", "permissions.p7s"):
        (enclave / name).write_text("not a real security file\n")
    line = _run(tmp_path / "ks", ros_domain_id)
    assert line.startswith("REFUSED"), line
    print(line)     # here: "This Fast DDS version doesn't have the security libraries ..."
