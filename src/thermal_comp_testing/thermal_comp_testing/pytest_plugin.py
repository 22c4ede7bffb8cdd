"""pytest plugin of thermal-comp (entry point ``pytest11``): an isolated ROS 2 environment
per test process, for the tests of every package, run by ``pytest`` or ``colcon test``.

Every process that runs tests (the pytest session, or each pytest-xdist worker under ``-n``)
takes a ROS_DOMAIN_ID no other running process holds (an flock on a file per id, see
``thermal_comp_common.runtime.domain_ids``), discovery is limited to localhost, and ROS logs go to a
temporary folder of its own, so concurrent test runs and workers never see each other's nodes.
"""
from __future__ import annotations

import os
import pathlib
import sys
import tempfile

import pytest

from thermal_comp_common.runtime.domain_ids import claim_domain_id

VENV_BIN = pathlib.Path(sys.executable).parent
SHARED_ENV = "THERMAL_COMP_SHARED"

MARKERS = {
    "slow": "end-to-end tests over several processes (run apart with -m slow; CI runs them)",
    "ros": "tests that start ROS 2 nodes (unique ROS_DOMAIN_ID per test process)",
}


def _shared_dir(config) -> pathlib.Path:
    """``$THERMAL_COMP_SHARED``, else ``shared/`` beside the repository pytest runs in."""
    env = os.environ.get(SHARED_ENV)
    if env:
        return pathlib.Path(env)
    root = pathlib.Path(config.rootpath)
    while root != root.parent and not (root / ".git").exists() and not (root / "setup.sh").exists():
        root = root.parent
    return root.parent / "shared"


def pytest_configure(config):
    # Registered here rather than in pyproject.toml, so `colcon test` (pytest in a package
    # folder, possibly outside this repository) accepts the marks under --strict-markers.
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")
    os.environ[SHARED_ENV] = str(_shared_dir(config))
    # Runs in every xdist worker too: a worker inherits the controller's environment, then
    # replaces the id and log folder with its own.
    os.environ["ROS_DOMAIN_ID"] = str(claim_domain_id())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    worker = getattr(config, "workerinput", {}).get("workerid", "main")  # xdist: gw0, gw1, ...
    log_dir = pathlib.Path(tempfile.mkdtemp(prefix=f"thermal_comp_roslog_{worker}_"))
    os.environ["ROS_LOG_DIR"] = str(log_dir)
    os.environ["ROS_HOME"] = str(log_dir)
    os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    os.environ["PYTHONUNBUFFERED"] = "1"
    # rerun and matplotlib write into HOME on first use; keep tests off the user's files.
    os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """The ROS_DOMAIN_ID of this test process (already exported to os.environ)."""
    return int(os.environ["ROS_DOMAIN_ID"])


@pytest.fixture(scope="session")
def venv_bin() -> pathlib.Path:
    return VENV_BIN


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    """The shared/ folder (specs, FL_THERMAL data): ``$THERMAL_COMP_SHARED``."""
    shared = pathlib.Path(os.environ[SHARED_ENV])
    if not shared.is_dir():
        pytest.fail(f"shared/ folder not found at {shared} (set {SHARED_ENV})")
    return shared


@pytest.fixture
def ros_context():
    """An initialised rclpy context for in-process nodes; shut down after the test."""
    import rclpy  # ROS only for the tests that ask for a context: the plugin loads in every run
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    yield ctx
    if ctx.ok():
        ctx.try_shutdown()
