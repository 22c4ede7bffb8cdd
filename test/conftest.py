"""Shared fixtures: an isolated ROS 2 environment per test session.

Every pytest session takes a ROS_DOMAIN_ID no other running session holds (an flock on a
file per id), discovery is limited to localhost, and ROS logs go to a temporary folder, so
concurrent test runs on one machine never see each other's nodes.
"""
from __future__ import annotations

import fcntl
import os
import pathlib
import sys
import tempfile

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
VENV_BIN = pathlib.Path(sys.executable).parent

_LOCK_DIR = pathlib.Path(tempfile.gettempdir()) / "thermal_comp_domain_locks"
_held_lock = None


def _claim_domain_id() -> int:
    """Claim a free ROS_DOMAIN_ID in 1..200 for this process (released at exit)."""
    global _held_lock
    _LOCK_DIR.mkdir(exist_ok=True)
    start = (os.getpid() % 200) + 1
    for k in range(200):
        did = (start + k - 1) % 200 + 1
        f = open(_LOCK_DIR / f"{did}.lock", "w")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        _held_lock = f
        return did
    raise RuntimeError("no free ROS_DOMAIN_ID in 1..200")


def pytest_configure(config):
    did = _claim_domain_id()
    os.environ["ROS_DOMAIN_ID"] = str(did)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    log_dir = pathlib.Path(tempfile.mkdtemp(prefix="thermal_comp_roslog_"))
    os.environ["ROS_LOG_DIR"] = str(log_dir)
    os.environ["ROS_HOME"] = str(log_dir)
    os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    os.environ["PYTHONUNBUFFERED"] = "1"
    # rerun and matplotlib write into HOME on first use; keep tests off the user's files.
    os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """The ROS_DOMAIN_ID of this test session (already exported to os.environ)."""
    return int(os.environ["ROS_DOMAIN_ID"])


@pytest.fixture(scope="session")
def venv_bin() -> pathlib.Path:
    return VENV_BIN


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    """The shared/ folder beside the repository (specs, FL_THERMAL data)."""
    if not SHARED.is_dir():
        pytest.fail(f"shared/ folder not found at {SHARED}")
    return SHARED


@pytest.fixture
def ros_context():
    """An initialised rclpy context for in-process nodes; shut down after the test."""
    import rclpy
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    yield ctx
    if ctx.ok():
        ctx.try_shutdown()
