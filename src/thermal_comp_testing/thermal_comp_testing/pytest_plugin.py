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


#: Fast DDS 2.x reads its default XML profiles from the file this variable names
PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: Discovery between the participants of one process goes over the transport; user data stays
#: in-process. Fast DDS 2.14 can deadlock deleting a writer when its discovery message is
#: delivered in-process to another participant (upstream Fast-DDS #6502, #6193): a test process
#: with several contexts then hangs where no timeout can interrupt it.
TEST_PROCESS_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <library_settings>
    <intraprocess_delivery>USER_DATA_ONLY</intraprocess_delivery>
  </library_settings>
</dds>
"""
_dds_configured = False


def configure_test_process_dds() -> bool:
    """Give this process's Fast DDS the test profile (unless the user names a profile): the
    library reads it when the first participant is made and keeps it, so the variable is
    set only for that moment and the processes the tests start never inherit it (the cell
    launcher would otherwise leave its own transport choice out). True if applied."""
    global _dds_configured
    if _dds_configured or os.environ.get(PROFILES_ENV):
        return False
    _dds_configured = True
    import rclpy  # ROS only where a ROS test runs: the plugin loads in every run
    path = pathlib.Path(os.environ["ROS_LOG_DIR"]) / "fastdds_test_process.xml"
    path.write_text(TEST_PROCESS_PROFILE)
    os.environ[PROFILES_ENV] = str(path)
    ctx = rclpy.context.Context()
    try:
        rclpy.init(context=ctx)
        rclpy.create_node("_thermal_comp_dds_profile", context=ctx).destroy_node()  # makes the participant
    finally:
        del os.environ[PROFILES_ENV]
        ctx.try_shutdown()
    return True


def pytest_runtest_setup(item):
    if item.get_closest_marker("ros") is not None:
        configure_test_process_dds()


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
