"""The workspace builds the ROS way: `colcon build` into a scratch folder installs every node
where `ros2 run` looks (install/PKG/lib/PKG/EXE), the launch files and config under
share/PKG/, and `colcon test` finds a package's tests and runs them with pytest.

colcon comes from requirements/colcon.txt (setup.sh installs it off the venv's import path as
.venv/bin/colcon). The whole workspace is built, the interface package thermal_comp_msgs too
(cmake), as docs/architecture.md says: `colcon test` of a package colcon did not build fails
("Failed to find .../thermal_comp_msgs/share/thermal_comp_msgs/package.sh"), so `colcon build &&
colcon test` must cover the same packages.
"""
from __future__ import annotations

import ast
import json
import os
import pathlib
import subprocess
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[4]
SRC = REPO / "src"
COLCON = pathlib.Path(sys.executable).parent / "colcon"
PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / "setup.py").is_file())
ALL_PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / "package.xml").is_file())
LAUNCH_FILES = ["cell.launch.py", "nmv5000_twin.launch.py"]
# share/PKG/config/... <- source files (relative to src/PKG)
CONFIG = {
    "thermal_twin": ("config/presets", "thermal_twin/presets/*.yaml"),
    "thermal_sensors": ("config", "thermal_sensors/config/*.yaml"),
    "talc_model": ("config", "talc_model/config/*.yaml"),
    "thermal_comp": ("config/cells", "../../config/cells/*.yaml"),
}


def console_scripts(pkg: str) -> list[str]:
    """Names of the console scripts a package's setup.py declares."""
    tree = ast.parse((SRC / pkg / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "entry_points":
            groups = ast.literal_eval(node.value)
            return [e.split("=")[0].strip() for e in groups.get("console_scripts", [])]
    return []


def _colcon(ws: pathlib.Path, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    if not COLCON.is_file():
        pytest.fail(f"{COLCON} missing: ./setup.sh installs colcon (requirements/colcon.txt)")
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix, COLCON_HOME=str(ws / "colcon_home"))
    env.pop("PYTHONPATH", None)
    return subprocess.run([str(COLCON), "--log-base", str(ws / "log"), *args,
                           "--base-paths", str(SRC), "--build-base", str(ws / "build"),
                           "--install-base", str(ws / "install")],
                          cwd=ws, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> pathlib.Path:
    ws = tmp_path_factory.mktemp("colcon_ws")
    r = _colcon(ws, "build", "--event-handlers", "console_direct-", timeout=1200)  # cmake: the interfaces
    assert r.returncode == 0, f"colcon build failed:\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"
    return ws


def _install_env(ws: pathlib.Path) -> dict[str, str]:
    """What sourcing install/setup.bash sets for these packages: prefixes and Python path."""
    prefixes = [str(ws / "install" / p) for p in PACKAGES]
    site = [str(ws / "install" / p / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
                / "site-packages") for p in PACKAGES]
    return dict(os.environ, AMENT_PREFIX_PATH=os.pathsep.join(prefixes + [sys.prefix]),
                PYTHONPATH=os.pathsep.join(site))


@pytest.mark.slow
def test_every_node_executable_is_where_ros2_run_looks(workspace):
    # ros2 run PKG EXE runs <prefix of PKG in the ament index>/lib/PKG/EXE (ros2cli has no
    # wheels here, so the same lookup is done with ament_index_python).
    expected = {pkg: console_scripts(pkg) for pkg in PACKAGES}
    assert sum(len(v) for v in expected.values()) >= 8
    lookup = ("import json, os, sys\n"
              "from ament_index_python.packages import get_package_prefix\n"
              "out = {}\n"
              "for pkg, exes in json.loads(sys.argv[1]).items():\n"
              "    lib = os.path.join(get_package_prefix(pkg), 'lib', pkg)\n"
              "    out[pkg] = sorted(e for e in exes if os.access(os.path.join(lib, e), os.X_OK))\n"
              "print(json.dumps(out))\n")
    r = subprocess.run([sys.executable, "-c", lookup, json.dumps(expected)], env=_install_env(workspace),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == {pkg: sorted(v) for pkg, v in expected.items()}
    assert not (workspace / "install" / "thermal_comp" / "bin").exists()


@pytest.mark.slow
def test_an_installed_executable_runs_from_the_install_space(workspace):
    env = _install_env(workspace)
    exe = workspace / "install" / "thermal_comp" / "lib" / "thermal_comp" / "thermal-comp"
    r = subprocess.run([str(exe), "--help"], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "launch" in r.stdout
    r = subprocess.run([sys.executable, "-c", "import thermal_comp; print(thermal_comp.__file__)"],
                       env=env, capture_output=True, text=True, timeout=60)
    assert pathlib.Path(r.stdout.strip()).is_relative_to(workspace / "install" / "thermal_comp")


@pytest.mark.slow
def test_launch_files_and_config_are_installed_under_share(workspace):
    share = workspace / "install" / "thermal_comp" / "share" / "thermal_comp"
    for name in LAUNCH_FILES:
        assert (share / "launch" / name).read_text() == (SRC / "thermal_comp" / "launch" / name).read_text()
    for pkg, (dest, pattern) in CONFIG.items():
        sources = sorted((SRC / pkg).glob(pattern))
        assert sources, pattern
        installed = workspace / "install" / pkg / "share" / pkg / dest
        assert sorted(p.name for p in installed.iterdir()) == sorted(p.name for p in sources)
        for src in sources:
            assert (installed / src.name).read_bytes() == src.read_bytes()
    for pkg in PACKAGES:
        assert (workspace / "install" / pkg / "share" / pkg / "package.xml").is_file()


@pytest.mark.slow
def test_colcon_test_finds_a_packages_tests(workspace):
    pkg = "thermal_comp_common"
    here = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "--collect-only", "-q",
                           str(SRC / pkg / "test")], capture_output=True, text=True, timeout=120, cwd=REPO)
    n_here = next(line for line in here.stdout.splitlines() if "collected" in line)
    r = _colcon(workspace, "test", "--packages-select", pkg, "--event-handlers", "console_direct+",
                "--pytest-args", "--collect-only", "-q")
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    assert n_here.split(" in ")[0] in r.stdout, (n_here, r.stdout[-3000:])
    assert int(n_here.split()[0]) > 0


def test_the_editable_venv_install_keeps_its_console_scripts():
    """setup.cfg moves colcon's scripts to lib/PKG; pip's editable install (setup.sh) still
    writes them to the venv's bin/, and the launcher still resolves them to modules."""
    from thermal_comp.cell.config import console_script_module
    bin_dir = pathlib.Path(sys.executable).parent
    for pkg in PACKAGES:
        for exe in console_scripts(pkg):
            assert os.access(bin_dir / exe, os.X_OK), f"{bin_dir / exe} missing: run ./setup.sh"
            module = console_script_module(pkg, exe)
            assert module is not None and module.startswith(f"{pkg}."), (pkg, exe, module)


@pytest.mark.slow
def test_colcon_test_of_the_whole_workspace_runs_every_package(workspace):
    """`colcon build && colcon test` over every package, the interface package included
    (collect-only: the tests themselves run in the suite), and `colcon test-result` is clean."""
    assert "thermal_comp_msgs" in ALL_PACKAGES and (workspace / "install" / "thermal_comp_msgs" / "share" /
                                                    "thermal_comp_msgs" / "package.sh").is_file()
    r = _colcon(workspace, "test", "--event-handlers", "console_direct-", "--pytest-args", "--collect-only", "-q",
                timeout=1200)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    assert f"Summary: {len(ALL_PACKAGES)} packages finished" in r.stdout, r.stdout[-2000:]
    env = dict(os.environ, COLCON_HOME=str(workspace / "colcon_home"))
    result = subprocess.run([str(COLCON), "test-result", "--test-result-base", str(workspace / "build")],
                            cwd=workspace, env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "0 errors, 0 failures" in result.stdout, result.stdout + result.stderr
