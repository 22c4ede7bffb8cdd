"""Every package's public names (``__all__``) import, and the ROS-free packages' names do not
pull in rclpy (checked in a fresh interpreter, since this one may have imported it already)."""
from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

ROS_FREE = ["thermal_comp_common", "thermal_twin", "thermal_sensors", "probe_cycle"]
WITH_ROS = ["thermal_comp", "thermal_eval"]


@pytest.mark.parametrize("package", ROS_FREE + WITH_ROS)
def test_public_names_import(package):
    pkg = importlib.import_module(package)
    assert pkg.__all__, f"{package} exports nothing"
    for name in pkg.__all__:
        value = getattr(pkg, name)
        assert value is not None
        assert name in dir(pkg)
        if hasattr(value, "__module__") and callable(value):
            assert value.__module__.startswith(package + "."), f"{package}.{name} comes from {value.__module__}"
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        getattr(pkg, "no_such_name")


@pytest.mark.parametrize("package", ROS_FREE)
def test_ros_free_public_names_do_not_import_rclpy(package):
    code = (f"import sys\nfrom {package} import *\nimport {package}\n"
            f"assert all(n in globals() for n in {package}.__all__)\n"
            "print('rclpy' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False", f"importing {package}'s public names imported rclpy"


def test_a_submodule_import_does_not_load_the_package_api():
    """Importing one module (as a node does) does not import every exported module."""
    code = ("import sys\nimport thermal_twin.machine.presets\n"
            "print('thermal_twin.diagnose.diagnosis' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


def test_a_name_listed_twice_is_an_error():
    from thermal_comp_common.public_api import lazy_exports
    with pytest.raises(ValueError, match="'x' listed under both 'a' and 'b'"):
        lazy_exports("somepkg", {"a": ["x"], "b": ["x"]})


def test_a_name_that_is_also_a_submodule_is_an_error():
    from thermal_comp_common.public_api import lazy_exports
    with pytest.raises(ValueError, match="also submodule names"):
        lazy_exports("somepkg", {"identify": ["identify"], "b": ["y"]})


def test_an_exported_function_is_not_shadowed_by_its_submodule_imported_first():
    import thermal_twin.identify.command  # noqa: F401  binds the submodules on the package first
    from thermal_twin.identify import identify
    assert callable(identify) and not isinstance(identify, type(thermal_twin))
