"""The cell launch files: the node list is the launcher's, and cell.launch.py builds it right.

launch/launch_ros have no wheels for this venv, so `ros2 launch` itself cannot run here. What is
tested: ``launch_plan`` as a pure function of the cell file, its agreement with the processes
``thermal-comp launch`` would start (argv, parameters file, environment), and the launch files
executed against recording doubles of the launch classes that accept only the keyword
arguments the Jazzy classes take.
"""
from __future__ import annotations

import ast
import importlib.util
import io
import pathlib
import sys
import tempfile
import types

import pytest
import yaml

from thermal_comp.cell.config import load_cell, parameters_file_text, parse_cell
from thermal_comp.cell.launch_plan import launch_plan
from thermal_comp.cell.launcher import Launcher

PKG = pathlib.Path(__file__).resolve().parents[2]
REPO = PKG.parents[1]
LAUNCH_DIR = PKG / "launch"
NMV5000_CELL = REPO / "config" / "cells" / "nmv5000_twin.yaml"
MODULE_CELL = pathlib.Path(__file__).resolve().parent / "cells" / "two_nodes.yaml"

# Keyword arguments of launch_ros.actions.Node / launch.actions.ExecuteProcess in Jazzy
# (Node passes what it does not take itself on to ExecuteProcess).
EXECUTE_PROCESS_KW = {"cmd", "name", "cwd", "env", "additional_env", "shell", "sigterm_timeout",
                      "sigkill_timeout", "emulate_tty", "output", "output_format", "log_cmd",
                      "on_exit", "respawn", "respawn_delay", "respawn_max_retries", "prefix",
                      "cached_output"}
NODE_KW = {"executable", "package", "name", "namespace", "exec_name", "parameters", "remappings",
           "ros_arguments", "arguments"} | (EXECUTE_PROCESS_KW - {"cmd"})


def test_plan_of_the_nmv5000_cell():
    cell = load_cell(NMV5000_CELL)
    plan = launch_plan(cell)
    assert [(n.name, n.package, n.executable) for n in plan] == [
        ("machine_sim", "thermal_twin", "machine_sim"),
        ("sensors", "thermal_sensors", "temperature_publisher"),
        ("probe_cycle", "probe_cycle", "probe_cycle_server"),
        ("model", "talc_model", "talc_model"),
        ("bridge", "cnc_bridge", "cnc_bridge"),
        ("recorder", "thermal_comp", "bag_recorder")]
    assert {n.namespace for n in plan} == {"/nmv5000"}
    assert all(n.env["ROS_DOMAIN_ID"] == "42" for n in plan)
    sim, sensors = plan[0], plan[1]
    assert (sim.respawn, sim.respawn_max_retries) == (False, -1)
    assert (sensors.respawn, sensors.respawn_delay_s, sensors.respawn_max_retries) == (True, 1.0, 5)
    params = yaml.safe_load(sensors.parameters_yaml)["/nmv5000/sensors"]["ros__parameters"]
    assert params == {"source": "twin", "sensor_config": "nmv5000", "lockstep_participant": True,
                      "use_sim_time": True}


@pytest.mark.parametrize("cell_file", [NMV5000_CELL, MODULE_CELL], ids=["executables", "modules"])
def test_plan_starts_what_the_launcher_starts(cell_file, tmp_path):
    cell = load_cell(cell_file)
    plan = launch_plan(cell)
    procs = Launcher([cell], run_dir=tmp_path, output=io.StringIO()).processes
    assert [p.node.name for p in procs] == [n.name for n in plan]
    for proc, spec in zip(procs, plan):
        params_file = proc.argv[proc.argv.index("--params-file") + 1]
        assert pathlib.Path(params_file).read_text() == spec.parameters_yaml
        assert proc.argv == [sys.executable, "-m", spec.module, *spec.arguments,
                             *spec.ros_arguments(params_file)]
        assert {k: proc.env[k] for k in spec.env} == spec.env
        assert spec.parameters_yaml == parameters_file_text(cell, proc.node)


def test_plan_of_module_nodes_has_no_package():
    plan = launch_plan(load_cell(MODULE_CELL))
    assert [(n.name, n.package, n.module) for n in plan] == [
        ("talker", None, "temperature_talker"), ("listener", None, "temperature_listener")]
    assert all("ROS_DOMAIN_ID" not in n.env for n in plan)  # the cell sets no domain id
    assert [(n.respawn_delay_s, n.respawn_max_retries) for n in plan] == [(0.5, 3)] * 2


class _Recorded:
    """Stands in for a launch class: checks and keeps its keyword arguments."""

    allowed: set[str] = set()

    def __init__(self, *args, **kwargs):
        unknown = set(kwargs) - self.allowed
        assert not unknown, f"{type(self).__name__} takes no {sorted(unknown)}"
        self.args, self.kwargs = args, kwargs


def _fake_launch_modules() -> dict[str, types.ModuleType]:
    def cls(name, allowed):
        return type(name, (_Recorded,), {"allowed": set(allowed)})

    class LaunchConfiguration:
        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return context[self.name]

    mods = {n: types.ModuleType(n) for n in ["launch", "launch.actions", "launch.substitutions",
                                             "launch.launch_description_sources", "launch_ros",
                                             "launch_ros.actions", "ament_index_python",
                                             "ament_index_python.packages"]}
    mods["launch"].LaunchDescription = lambda actions: list(actions)
    acts = mods["launch.actions"]
    acts.DeclareLaunchArgument = cls("DeclareLaunchArgument", {"default_value", "description", "choices"})
    acts.OpaqueFunction = cls("OpaqueFunction", {"function", "args", "kwargs"})
    acts.ExecuteProcess = cls("ExecuteProcess", EXECUTE_PROCESS_KW)
    acts.IncludeLaunchDescription = cls("IncludeLaunchDescription", {"launch_arguments"})
    mods["launch.substitutions"].LaunchConfiguration = LaunchConfiguration
    mods["launch.launch_description_sources"].PythonLaunchDescriptionSource = cls("PythonLaunchDescriptionSource", set())
    mods["launch_ros.actions"].Node = cls("Node", NODE_KW)
    mods["ament_index_python.packages"].get_package_share_directory = lambda pkg: f"/opt/share/{pkg}"
    return mods


def _load_launch_file(name: str, monkeypatch) -> types.ModuleType:
    for mod_name, mod in _fake_launch_modules().items():
        monkeypatch.setitem(sys.modules, mod_name, mod)
    spec = importlib.util.spec_from_file_location(name.replace(".", "_"), LAUNCH_DIR / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("cell_file", [NMV5000_CELL, MODULE_CELL], ids=["executables", "modules"])
def test_cell_launch_file_builds_the_plan(cell_file, monkeypatch, tmp_path):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where the launch file writes
    module = _load_launch_file("cell.launch.py", monkeypatch)
    declare, opaque = module.generate_launch_description()
    assert declare.args == ("cell_file",)
    actions = opaque.kwargs["function"]({"cell_file": str(cell_file)})
    plan = launch_plan(load_cell(cell_file))
    drivers = {a.kwargs["name"]: a for a in actions if a.kwargs.get("name", "").endswith("_lifecycle")}
    actions = [a for a in actions if a.kwargs.get("name", "") not in drivers]
    assert len(actions) == len(plan)
    managed = [spec for spec in plan if spec.lifecycle]
    assert sorted(drivers) == sorted(f"{load_cell(cell_file).cell}_{s.name}_lifecycle" for s in managed)
    for spec in managed:   # configure + activate by the launcher's own driver, in the node's environment
        kw = drivers[f"{load_cell(cell_file).cell}_{spec.name}_lifecycle"].kwargs
        assert kw["cmd"] == spec.lifecycle_command(sys.executable)
        assert kw["cmd"][-2:] == ["configure", "activate"] and kw["additional_env"] == spec.env
    for action, spec in zip(actions, plan):
        kw = action.kwargs
        params_file = pathlib.Path(kw["parameters"][0] if spec.package else kw["cmd"][-1])
        assert params_file.read_text() == spec.parameters_yaml
        assert (kw["respawn"], kw["respawn_delay"], kw["respawn_max_retries"]) == \
            (spec.respawn, spec.respawn_delay_s, spec.respawn_max_retries)
        assert kw["additional_env"] == spec.env
        if spec.package:
            assert type(action).__name__ == "Node"
            assert (kw["package"], kw["executable"], kw["name"], kw["namespace"], kw["arguments"]) == \
                (spec.package, spec.executable, spec.name, spec.namespace, spec.arguments)
        else:
            assert type(action).__name__ == "ExecuteProcess"
            assert kw["cmd"] == [sys.executable, "-m", spec.module, *spec.arguments,
                                 *spec.ros_arguments(str(params_file))]


def test_nmv5000_launch_file_includes_the_cell_launch_with_the_installed_cell(monkeypatch):
    module = _load_launch_file("nmv5000_twin.launch.py", monkeypatch)
    (include,) = module.generate_launch_description()
    (source,) = include.args
    assert source.args == ("/opt/share/thermal_comp/launch/cell.launch.py",)
    assert dict(include.kwargs["launch_arguments"]) == {
        "cell_file": "/opt/share/thermal_comp/config/cells/nmv5000_twin.yaml"}


def test_launch_files_import_only_launch_and_our_packages():
    allowed = {"launch", "launch_ros", "ament_index_python", "thermal_comp", "os", "pathlib", "sys",
               "tempfile"}
    files = sorted(LAUNCH_DIR.glob("*.launch.py"))
    assert [f.name for f in files] == ["cell.launch.py", "nmv5000_twin.launch.py"]
    for f in files:
        tree = ast.parse(f.read_text(), filename=str(f))
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names} | \
                {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert {n.split(".")[0] for n in names} <= allowed, f.name
        assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description"
                   for n in tree.body), f.name


def _crash_cell(tmp_path, restart: dict):
    """machine_sim exits 3 at once; two other nodes would run until stopped."""
    (tmp_path / "sim_crash.py").write_text("print('machine_sim up', flush=True)\nraise SystemExit(3)\n")
    (tmp_path / "wait_forever.py").write_text("import signal\nprint('up', flush=True)\nsignal.pause()\n")
    env = {"PYTHONPATH": str(tmp_path)}
    doc = {"cell": "crashcell", "nodes": [
        {"name": "machine_sim", "module": "sim_crash", "env": env, "restart": restart},
        {"name": "model", "module": "wait_forever", "env": env},
        {"name": "recorder", "module": "wait_forever", "env": env}]}
    return parse_cell(doc, source="test cell", resolve=False)


@pytest.mark.parametrize("restart, why", [({"enabled": False}, "restart off"),
                                          ({"enabled": True, "max_restarts": 1, "backoff_s": 0.1},
                                           "restart limit reached")])
def test_a_crashed_node_that_is_not_restarted_ends_the_cell(tmp_path, restart, why):
    out = io.StringIO()
    launcher = Launcher([_crash_cell(tmp_path, restart)], run_dir=tmp_path / "run", output=out, grace_s=5.0)
    assert launcher.run(poll_s=0.05) == 1
    lines = [ln for ln in out.getvalue().splitlines() if "crashcell/machine_sim exited" in ln]
    assert lines[-1] == (f"[launch] crashcell/machine_sim exited with code 3 and is not restarted ({why}): "
                         "the cell cannot go on without it; stopping every node"), out.getvalue()
    assert launcher.ended_by == "crashcell/machine_sim"
    assert all(mp.popen.poll() is not None for mp in launcher.processes)   # nothing left running
    assert len(lines) == 1 + ("limit" in why)      # the crash before the restart, then the last one
    assert "crashcell/model exited" not in out.getvalue()   # the stopped nodes are no crash of their own
