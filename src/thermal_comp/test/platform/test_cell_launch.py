"""The cell launch files: the node list is the launcher's, and cell.launch.py builds it right.

launch/launch_ros cannot be installed here (no wheels, no Debian package: docs/launch.md), so
`ros2 launch` itself cannot run. What is tested: ``launch_plan`` and the launch arguments as pure
functions of the cell file, their agreement with the processes ``thermal-comp launch`` would
start (argv, parameters file, environment), the launch files' actions against doubles that
accept only the keyword arguments of the Jazzy classes, and cell.launch.py run by
``launch_double``: real processes, launch's events, and the bridge's lifecycle driven by
ChangeState / OnStateTransition over its real transition_event topic and change_state service.
"""
from __future__ import annotations

import ast
import importlib.util
import io
import os
import pathlib
import sys
import tempfile
import types

import pytest
import yaml

from cnc_bridge.cnc_emulator import free_tcp_port
from thermal_comp.cell.config import CellConfigError, load_cell, parameters_file_text, parse_cell
from thermal_comp.cell import cell_lock
from thermal_comp.cell.launch_plan import LAUNCH_ARGUMENTS, launch_arguments_text, launch_plan, resolve_cell

import launch_double
from ros_helpers import PROCS
from thermal_comp.cell.launcher import Launcher

PKG = pathlib.Path(__file__).resolve().parents[2]
REPO = PKG.parents[1]
LAUNCH_DIR = PKG / "launch"
NMV5000_CELL = REPO / "config" / "cells" / "nmv5000_twin.yaml"
MODULE_CELL = pathlib.Path(__file__).resolve().parent / "cells" / "two_nodes.yaml"

def test_plan_of_the_nmv5000_cell():
    cell = load_cell(NMV5000_CELL)
    plan = launch_plan(cell)
    assert [(n.name, n.package, n.executable) for n in plan] == [
        ("machine_sim", "thermal_twin", "machine_sim"),
        ("sensors", "thermal_sensors", "temperature_publisher"),
        ("probe_cycle", "probe_cycle", "probe_cycle_server"),
        ("model", "talc_model", "talc_model"),
        ("bridge", "cnc_bridge", "cnc_bridge"),
        ("frames", "thermal_comp", "static_frames"),
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


def _load_launch_file(name: str, monkeypatch) -> types.ModuleType:
    """The launch file on the doubles; its cell locks in this test's own folder."""
    monkeypatch.setattr(cell_lock, "LOCK_DIR", pathlib.Path(tempfile.mkdtemp(prefix="cell_locks_")))
    for mod_name, mod in launch_double.modules().items():
        monkeypatch.setitem(sys.modules, mod_name, mod)
    spec = importlib.util.spec_from_file_location(name.replace(".", "_"), LAUNCH_DIR / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _Context:
    def __init__(self, **configs):
        self.launch_configurations = configs


@pytest.mark.parametrize("cell_file", [NMV5000_CELL, MODULE_CELL], ids=["executables", "modules"])
def test_cell_launch_file_builds_the_plan(cell_file, monkeypatch, tmp_path):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where the launch file writes
    cell = load_cell(cell_file)
    if cell.domain_id is not None:
        monkeypatch.setenv("ROS_DOMAIN_ID", str(cell.domain_id))
    module = _load_launch_file("cell.launch.py", monkeypatch)
    *declares, opaque = module.generate_launch_description()
    assert [d.args[0] for d in declares] == [a.name for a in LAUNCH_ARGUMENTS] == ["cell_file", "namespace", "domain_id"]
    assert "default_value" not in declares[0].kwargs and all(d.kwargs["default_value"] == "" for d in declares[1:])
    actions = opaque.kwargs["function"](_Context(cell_file=str(cell_file), namespace="", domain_id=""))
    plan = launch_plan(cell)
    nodes = [a for a in actions if type(a).__name__ in ("Node", "LifecycleNode")]
    assert len(nodes) == len(plan)
    for action, spec in zip(nodes, plan):
        kw = action.kwargs
        assert type(action).__name__ == ("LifecycleNode" if spec.lifecycle else "Node")
        assert pathlib.Path(kw["parameters"][0]).read_text() == spec.parameters_yaml
        assert (kw["respawn"], kw["respawn_delay"], kw["respawn_max_retries"]) == \
            (spec.respawn, spec.respawn_delay_s, spec.respawn_max_retries)
        assert kw["additional_env"] == spec.env
        assert (kw["package"], kw["name"], kw["namespace"]) == (spec.package, spec.name, spec.namespace)
        assert (kw["executable"], kw["arguments"]) == spec.node_arguments(sys.executable)
        handlers = [a.kwargs["event_handler"] for a in actions if type(a).__name__ == "RegisterEventHandler"]
        mine = [h for h in handlers if action in (h.kwargs.get("target_action"), h.kwargs.get("target_lifecycle_node"))]
        kinds = sorted(type(h).__name__ for h in mine)
        assert kinds == (["OnProcessExit", "OnProcessStart"] + ["OnStateTransition"] * 4 if spec.lifecycle
                         else ["OnProcessExit"])
        # configure at the first start only: a respawned bridge stays unconfigured (writes nothing)
        assert all(h.kwargs["handle_once"] for h in mine if type(h).__name__ == "OnProcessStart")


def test_nmv5000_launch_file_includes_the_cell_launch_with_the_installed_cell(monkeypatch):
    module = _load_launch_file("nmv5000_twin.launch.py", monkeypatch)
    (include,) = module.generate_launch_description()
    (source,) = include.args
    assert source.args == ("/opt/share/thermal_comp/launch/cell.launch.py",)
    assert dict(include.kwargs["launch_arguments"]) == {
        "cell_file": "/opt/share/thermal_comp/config/cells/nmv5000_twin.yaml"}


def test_launch_files_import_only_launch_and_our_packages():
    allowed = {"launch", "launch_ros", "ament_index_python", "lifecycle_msgs", "thermal_comp", "os",
               "pathlib", "sys", "tempfile"}
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


# --- cell.launch.py run by the launch double: real processes, launch's events, the bridge's
# --- lifecycle over its transition_event topic and change_state service (see launch_double)

def _run_launch_file(tmp_path, monkeypatch, ros_context, doc: dict, until, timeout_s=120.0):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text(yaml.safe_dump(doc))
    module = _load_launch_file("cell.launch.py", monkeypatch)
    runner = launch_double.MiniLaunch(ros_context)
    runner.run(module.generate_launch_description(), {"cell_file": str(cell_file)}, until, timeout_s)
    return runner


def _bridge_doc(cell: str, domain_id: int, restart: dict, **params) -> dict:
    return {"cell": cell, "domain_id": domain_id, "nodes": [
        {"name": "bridge", "module": "cnc_bridge.cnc_bridge_node", "parameters": params, "restart": restart}]}


@pytest.mark.ros
@pytest.mark.slow
def test_launch_file_configures_and_activates_the_bridge_by_events(tmp_path, monkeypatch, ros_context,
                                                                   ros_domain_id):
    def until(run):
        return "[launch] /lcl/bridge: configured and active" in run.lines

    run = _run_launch_file(tmp_path, monkeypatch, ros_context, _bridge_doc(
        "lcl", ros_domain_id, {"enabled": True, "max_restarts": 2, "backoff_s": 0.5}, backend="twin"), until)
    assert run.shutdown_reason is None
    steps = [(start, goal) for node, start, goal in run.transitions if node == "/lcl/bridge"]
    assert steps == [("unconfigured", "configuring"), ("configuring", "inactive"),
                     ("inactive", "activating"), ("activating", "active")], steps
    assert any("active: writing offsets" in ln for ln in run.lines)


@pytest.mark.ros
@pytest.mark.slow
def test_launch_file_ends_the_cell_when_the_bridge_cannot_configure(tmp_path, monkeypatch, ros_context,
                                                                    ros_domain_id):
    run = _run_launch_file(tmp_path, monkeypatch, ros_context, _bridge_doc(
        "lcl_bad", ros_domain_id, {"enabled": True, "max_restarts": 2, "backoff_s": 0.5}, backend="opcua",
        connect_timeout_s=1.0, endpoint=f"opc.tcp://127.0.0.1:{free_tcp_port()}/nobody"), lambda run: False)
    assert run.shutdown_reason == "/lcl_bad/bridge: configure failed"
    assert "[launch] ERROR /lcl_bad/bridge: transition 'configure' failed (see the node's log); " \
           "stopping the cell" in run.lines
    assert ("/lcl_bad/bridge", "configuring", "unconfigured") in run.transitions
    assert not any(goal == "active" for _, _, goal in run.transitions)


@pytest.mark.ros
def test_launch_file_ends_the_cell_when_a_node_without_restart_crashes(tmp_path, monkeypatch, ros_context):
    doc = {"cell": "crash", "nodes": [
        {"name": "machine_sim", "module": "sim_crash", "env": {"PYTHONPATH": str(tmp_path)}},
        {"name": "model", "module": "wait_forever", "env": {"PYTHONPATH": str(tmp_path)}}]}
    _crash_cell(tmp_path, {"enabled": False})       # writes the two node modules
    run = _run_launch_file(tmp_path, monkeypatch, ros_context, doc, lambda run: False)
    assert run.shutdown_reason == "/crash/machine_sim exited with code 3"
    assert "[launch] /crash/machine_sim exited with code 3 and is not restarted: the cell cannot go on " \
           "without it; stopping every node" in run.lines


def test_launch_arguments_set_namespace_and_domain_and_refuse_bad_values(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    cell = resolve_cell(str(NMV5000_CELL))
    assert (cell.namespace, cell.domain_id) == ("/nmv5000", 42)
    cell = resolve_cell(str(NMV5000_CELL), namespace="/line2_nmv", domain_id="42")
    assert cell.namespace == "/line2_nmv"
    assert {n.env["ROS_DOMAIN_ID"] for n in launch_plan(cell)} == {"42"}
    assert all(n.namespace == "/line2_nmv" and f"'/line2_nmv/{n.name}':" in n.parameters_yaml
               for n in launch_plan(cell))
    for ns in ("/a/b", "2cell", "/"):
        with pytest.raises(CellConfigError, match=rf"launch argument namespace: .* got '{ns}'"):
            resolve_cell(str(NMV5000_CELL), namespace=ns)
    for did in ("233", "-1", "x"):
        with pytest.raises(CellConfigError, match=rf"launch argument domain_id: .* got '{did}'"):
            resolve_cell(str(NMV5000_CELL), domain_id=did)
    # the bridge is managed: its transitions come from the launch process, on its own domain
    with pytest.raises(CellConfigError, match=r"runs on ROS_DOMAIN_ID 7, this launch on 42: .* "
                                              r"\['bridge'\] .* ROS_DOMAIN_ID=7 ros2 launch"):
        resolve_cell(str(NMV5000_CELL), domain_id="7")
    monkeypatch.delenv("ROS_DOMAIN_ID")
    assert resolve_cell(str(MODULE_CELL), domain_id="7").domain_id == 7   # no managed node: any domain


def test_docs_list_the_launch_arguments_as_ros2_launch_s_does():
    text = (REPO / "docs" / "launch.md").read_text()
    block = text.split("<!-- launch-arguments -->\n```\n")[1].split("```\n<!-- /launch-arguments -->")[0]
    assert block == launch_arguments_text()


def test_a_second_launch_of_a_running_cell_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    module = _load_launch_file("cell.launch.py", monkeypatch)
    context = _Context(cell_file=str(MODULE_CELL), namespace="", domain_id="")
    module._cell_actions(context)
    with pytest.raises(cell_lock.CellLockError, match=rf"cell /example on ROS_DOMAIN_ID \d+ runs already \(pid {os.getpid()}"):
        module._cell_actions(context)
    module._LOCKS.pop().release()


@pytest.mark.ros
@pytest.mark.slow
def test_launch_file_ends_the_cell_when_a_managed_node_is_not_active_in_time(tmp_path, monkeypatch, ros_context):
    """A node marked lifecycle that has no lifecycle services: nothing waits forever."""
    doc = {"cell": "lcl_plain", "env": {"PYTHONPATH": str(PROCS)}, "nodes": [
        {"name": "talker", "module": "temperature_talker", "lifecycle": True, "lifecycle_timeout_s": 1,
         "parameters": {"period_s": 0.5}}]}
    run = _run_launch_file(tmp_path, monkeypatch, ros_context, doc, lambda run: False)
    assert run.shutdown_reason == "/lcl_plain/talker: not active within 3 s"
    assert "[launch] ERROR /lcl_plain/talker: not active within 3 s of its start (configure and activate); " \
           "stopping the cell" in run.lines
