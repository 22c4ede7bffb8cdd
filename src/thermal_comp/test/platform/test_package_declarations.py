"""Every package declares exactly what it imports, and the package graph is the documented DAG.

Each module of each ament_python package under src/ is parsed (module- and function-level
imports, launch files included); its third-party imports are mapped to rosdep keys by the one
table below and compared with package.xml in both directions (an undeclared import fails, a
declared key nothing imports fails), tests against test_depend, library keys against setup.py's
install_requires. Imports between our packages must follow the DAG order (lower never imports
higher). Cross-package imports inside functions are allowed now that the graph is a DAG, but
reported (a warning here; ``python THIS_FILE`` prints them) so they can be hoisted.
Rosdep keys: ROS packages by name, python3-* keys of rosdistro's rosdep/python.yaml, and for
libraries rosdistro has no key for, the python3-NAME-pip keys of rosdep/thermal_comp.yaml
(docs/architecture.md, "Dependencies and rosdep keys").
"""
from __future__ import annotations

import ast
import functools
import pathlib
import sys
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import pytest
import yaml

REPO = pathlib.Path(__file__).resolve().parents[4]
SRC = REPO / "src"
ROSDEP_FILE = REPO / "rosdep" / "thermal_comp.yaml"

# The DAG, lowest first: a package may import only packages of a lower level.
DAG_LEVELS = [["thermal_comp_msgs"], ["thermal_comp_common"], ["thermal_comp_testing"],
              ["thermal_twin"], ["thermal_sensors", "probe_cycle", "cnc_bridge"], ["talc_model"],
              ["thermal_comp"], ["thermal_eval"]]
LEVEL = {pkg: i for i, level in enumerate(DAG_LEVELS) for pkg in level}

# The test-support package: its pytest plugin (entry point pytest11) gives the tests their
# fixtures and markers without an import. Every package above it declares it as a test_depend;
# thermal_comp_common, below it (the plugin imports its domain ids), gets the plugin from the
# environment, since declaring it would be a cycle for colcon.
TEST_SUPPORT = "thermal_comp_testing"
TESTS_RUN_UNDER = {pkg: {TEST_SUPPORT} for pkg in LEVEL if LEVEL[pkg] > LEVEL[TEST_SUPPORT]}

# ROS 2 packages imported by our code: the rosdep key is the package name.
ROS_PACKAGES = {"rclpy", "std_msgs", "std_srvs", "builtin_interfaces", "rosgraph_msgs",
                "diagnostic_msgs", "lifecycle_msgs", "rcl_interfaces", "action_msgs", "launch", "launch_ros",
                "ament_index_python", "unique_identifier_msgs", "geometry_msgs", "tf2_msgs"}

# Python module -> (rosdep key, PyPI distribution). Keys without "-pip" are in rosdistro's
# rosdep/python.yaml; the "-pip" ones are defined in rosdep/thermal_comp.yaml.
LIBRARIES = {
    "numpy": ("python3-numpy", "numpy"),
    "scipy": ("python3-scipy", "scipy"),
    "yaml": ("python3-yaml", "pyyaml"),
    "sklearn": ("python3-sklearn", "scikit-learn"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "pandas": ("python3-pandas", "pandas"),
    "psutil": ("python3-psutil", "psutil"),
    "pymodbus": ("python3-pymodbus", "pymodbus"),
    "serial": ("python3-serial", "pyserial"),
    "tqdm": ("python3-tqdm", "tqdm"),
    "cryptography": ("python3-cryptography", "cryptography"),
    "pytest": ("python3-pytest", "pytest"),
    "hypothesis": ("python3-hypothesis", "hypothesis"),
    "websocket": ("python3-websocket", "websocket-client"),
    "PIL": ("python3-pil", "pillow"),
    "asyncua": ("python3-asyncua-pip", "asyncua"),
    "statsmodels": ("python3-statsmodels-pip", "statsmodels"),
    "rich": ("python3-rich-pip", "rich"),
    "mcap": ("python3-mcap-pip", "mcap"),
    "mcap_ros2": ("python3-mcap-ros2-support-pip", "mcap-ros2-support"),
    "rosbags": ("python3-rosbags-pip", "rosbags"),
    "rerun": ("python3-rerun-sdk-pip", "rerun-sdk"),
    "threadpoolctl": ("python3-threadpoolctl-pip", "threadpoolctl"),
    "sysidentpy": ("python3-sysidentpy-pip", "sysidentpy"),
    "distributed": ("python3-distributed-pip", "distributed"),
    "dask": ("python3-dask-pip", "dask"),
    "cloudpickle": ("python3-cloudpickle-pip", "cloudpickle"),
}

# Tests of a lower package that import a higher one (they test evaluation code and belong in
# that package's test folder). Allowed for tests only, these pairs only, and reported; never
# declared as test_depend, which would be a cycle for colcon.
TESTS_IMPORTING_UP = {("talc_model", "thermal_eval"), ("thermal_twin", "thermal_eval"),
                      ("thermal_comp", "thermal_eval"), ("probe_cycle", "cnc_bridge")}


@dataclass(frozen=True)
class Import:
    path: str          # relative to the repository
    line: int
    module: str        # dotted name as written
    in_function: bool

    @property
    def top(self) -> str:
        return self.module.split(".")[0]


def ament_python_packages() -> list[str]:
    return sorted(p.name for p in SRC.iterdir() if (p / "setup.py").is_file() and (p / "package.xml").is_file())


@functools.lru_cache(maxsize=None)
def imports_of(path: pathlib.Path) -> tuple[Import, ...]:
    """Absolute imports of one file, with whether each sits inside a function."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[Import] = []
    rel = str(path.relative_to(REPO))

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                found.extend(Import(rel, child.lineno, a.name, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                found.append(Import(rel, child.lineno, child.module, in_function))
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(tree, False)
    return tuple(found)


def package_files(pkg: str) -> tuple[list[pathlib.Path], list[pathlib.Path]]:
    """(code files: the Python package and launch files, test files)."""
    root = SRC / pkg
    code = sorted((root / pkg).rglob("*.py")) + sorted((root / "launch").glob("*.py"))
    return code, sorted((root / "test").rglob("*.py"))


def local_test_modules(pkg: str) -> set[str]:
    """Helper modules a package's tests import by bare name (conftest puts their folder on sys.path)."""
    test_dir = SRC / pkg / "test"
    return {p.stem for p in test_dir.rglob("*.py")} | {p.name for p in test_dir.rglob("*") if p.is_dir()}


def key_of(module: str) -> str | None:
    """Rosdep key of a top-level module; None for the standard library."""
    if module in sys.stdlib_module_names or module == "__future__":
        return None
    if module in LEVEL or module in ROS_PACKAGES:
        return module
    if module in LIBRARIES:
        return LIBRARIES[module][0]
    raise KeyError(module)


def declared(pkg: str) -> tuple[set[str], set[str]]:
    """(exec keys: exec_depend + depend, test_depend keys) of a package.xml."""
    root = ET.parse(SRC / pkg / "package.xml").getroot()
    tags = lambda *names: {e.text.strip() for n in names for e in root.iter(n)}  # noqa: E731
    return tags("exec_depend", "depend"), tags("test_depend")


def install_requires(pkg: str) -> set[str]:
    tree = ast.parse((SRC / pkg / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "install_requires":
            return set(ast.literal_eval(node.value))
    return set()


# Dependencies no import shows: package -> {key: why}.
RUNTIME_ONLY = {
    "thermal_comp_common": {"thermal_comp_msgs": "msg_definitions reads its installed .msg files"},
    "thermal_comp": {p: "runs the nodes of the cells it launches (config/cells, the demo)"
                     for p in ["thermal_twin", "thermal_sensors", "probe_cycle", "talc_model", "cnc_bridge"]},
}


def _against_dag(pkg: str, imp: Import) -> bool:
    return imp.top in LEVEL and imp.top != pkg and LEVEL[imp.top] >= LEVEL[pkg]


def _test_importing_up(pkg: str, imp: Import) -> bool:
    return (pkg, imp.top) in TESTS_IMPORTING_UP and imp.path.startswith(f"src/{pkg}/test/")


def used_keys(pkg: str, files: list[pathlib.Path], skip_up: bool = False) -> set[str]:
    local = local_test_modules(pkg)
    keys = set()
    for f in files:
        for imp in imports_of(f):
            if imp.top in local or imp.top == pkg or (skip_up and _test_importing_up(pkg, imp)):
                continue
            key = key_of(imp.top)
            if key is not None:
                keys.add(key)
    return keys


PACKAGES = ament_python_packages()


def test_every_package_is_in_the_dag():
    assert set(PACKAGES) | {"thermal_comp_msgs"} == set(LEVEL)


def test_every_import_is_known():
    """Every third-party module any package imports has a row in the table (or is stdlib)."""
    unknown = []
    for pkg in PACKAGES:
        local = local_test_modules(pkg)
        code, tests = package_files(pkg)
        for f in code + tests:
            for imp in imports_of(f):
                try:
                    key_of(imp.top)
                except KeyError:
                    if imp.top not in local:
                        unknown.append(f"{imp.path}:{imp.line} {imp.module}")
    assert not unknown, "imports with no rosdep key in the table: " + ", ".join(unknown)


@pytest.mark.parametrize("pkg", PACKAGES)
def test_no_import_against_the_dag(pkg):
    code, tests = package_files(pkg)
    imports = [i for f in code + tests for i in imports_of(f)]
    bad = [f"{i.path}:{i.line} imports {i.module}" for i in imports
           if _against_dag(pkg, i) and not _test_importing_up(pkg, i)]
    assert not bad, f"{pkg} (level {LEVEL[pkg]}) imports a package at its level or above: {bad}"
    # Allowed, but reported so they can be cleaned up: tests importing up (they should move
    # up) and cross-package imports inside functions (no cycle to dodge any more: hoist them).
    up = [i for i in imports if _against_dag(pkg, i)]
    in_functions = [i for i in imports if i.in_function and i.top in LEVEL
                    and i.top not in (pkg, "thermal_comp_msgs") and not _against_dag(pkg, i)]
    for what, found in [("test imports of a higher package (move the test)", up),
                        ("cross-package imports inside functions (hoist them)", in_functions)]:
        if found:
            warnings.warn(f"{pkg}: {len(found)} {what}:\n" +
                          "\n".join(f"  {i.path}:{i.line} {i.module}" for i in found), stacklevel=1)


@pytest.mark.parametrize("pkg", PACKAGES)
def test_package_xml_declares_exactly_the_imports(pkg):
    code, tests = package_files(pkg)
    exec_keys, test_keys = declared(pkg)
    code_keys = used_keys(pkg, code) | set(RUNTIME_ONLY.get(pkg, {}))
    assert sorted(code_keys - exec_keys) == [], f"{pkg}: imported but not an exec_depend"
    assert sorted(exec_keys - code_keys) == [], f"{pkg}: exec_depend that no module imports"
    tests_use = used_keys(pkg, tests, skip_up=True) | TESTS_RUN_UNDER.get(pkg, set())
    assert sorted(tests_use - exec_keys - test_keys) == [], f"{pkg}: tests import an undeclared package"
    assert sorted(test_keys - tests_use) == [], f"{pkg}: test_depend that no test imports"
    assert sorted(test_keys & exec_keys) == [], f"{pkg}: test_depend already an exec_depend"


@pytest.mark.parametrize("pkg", PACKAGES)
def test_declared_dependencies_follow_the_dag(pkg):
    """colcon orders packages by every dependency category: a test_depend upwards is a cycle."""
    exec_keys, test_keys = declared(pkg)
    ours = {k for k in exec_keys | test_keys if k in LEVEL}
    assert all(LEVEL[k] < LEVEL[pkg] for k in ours), f"{pkg}: depends on {sorted(ours)}"


def test_ground_package_depends_only_on_interfaces_rclpy_messages_and_libraries():
    exec_keys, _ = declared("thermal_comp_common")
    ours = {k for k in exec_keys if k in LEVEL}
    ros = {k for k in exec_keys if k in ROS_PACKAGES}
    assert ours == {"thermal_comp_msgs"}
    assert all(k == "rclpy" or k.endswith(("_msgs", "_interfaces")) for k in ros), sorted(ros)


def _known_rosdep_keys() -> dict[str, list[str]]:
    """The -pip keys of rosdep/thermal_comp.yaml -> their pip packages (same on every OS)."""
    doc = yaml.safe_load(ROSDEP_FILE.read_text())
    out = {}
    for key, per_os in doc.items():
        packages = {tuple(v["pip"]["packages"]) for v in per_os.values()}
        assert len(packages) == 1, f"{ROSDEP_FILE.name}: {key} names different pip packages per OS"
        out[key] = list(packages.pop())
    return out


def test_every_declared_key_resolves():
    pip_keys = _known_rosdep_keys()
    for module, (key, pypi) in LIBRARIES.items():
        if key.endswith("-pip"):
            assert pip_keys.get(key) == [pypi], f"{key} ({module}) missing or wrong in {ROSDEP_FILE.name}"
    assert set(pip_keys) == {k for k, _ in LIBRARIES.values() if k.endswith("-pip")}
    table = {k for k, _ in LIBRARIES.values()} | ROS_PACKAGES | set(LEVEL)
    for pkg in PACKAGES:
        exec_keys, test_keys = declared(pkg)
        assert sorted((exec_keys | test_keys) - table) == [], f"{pkg}: keys not in the table"


@pytest.mark.parametrize("pkg", PACKAGES)
def test_install_requires_names_the_imported_libraries(pkg):
    code, _ = package_files(pkg)
    pypi_of_key = {key: dist for key, dist in LIBRARIES.values()}
    wanted = {pypi_of_key[k] for k in used_keys(pkg, code) if k in pypi_of_key} | {"setuptools"}
    assert install_requires(pkg) == wanted


def cross_package_function_imports() -> list[Import]:
    out = []
    for pkg in PACKAGES:
        code, tests = package_files(pkg)
        out += [i for f in code + tests for i in imports_of(f)
                if i.in_function and i.top in LEVEL and i.top not in (pkg, "thermal_comp_msgs")]
    return out


def upward_test_imports() -> list[Import]:
    out = []
    for pkg in PACKAGES:
        _, tests = package_files(pkg)
        out += [i for f in tests for i in imports_of(f) if _against_dag(pkg, i)]
    return out


if __name__ == "__main__":
    print("cross-package imports inside functions:")
    for imp in cross_package_function_imports():
        print(f"  {imp.path}:{imp.line} {imp.module}")
    print("tests that import a higher package:")
    for imp in upward_test_imports():
        print(f"  {imp.path}:{imp.line} {imp.module}")
