"""What `ros2 launch thermal_comp cell.launch.py cell_file:=CELL.yaml` starts, as plain data.

The launch file (``launch/cell.launch.py``) turns each :class:`NodeLaunch` into a launch_ros
``Node``, or a ``LifecycleNode`` for a managed node, whose configure and activate are
``ChangeState`` events sent on its ``OnStateTransition`` events. It is computed here from a
parsed cell file and the launch arguments (:data:`LAUNCH_ARGUMENTS`, :func:`resolve_cell`),
with the same parameters-file text, namespace, node name, arguments and environment as
``thermal-comp launch`` (``launcher.py``), so the two ways to start a cell are equivalent by
construction. Kept free of ``launch`` imports: launch has no wheels for this venv, and the
plan is tested as a pure function of the cell file.
"""
from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field

from thermal_comp_common.runtime.dds_transport import PROFILES_ENV, TRANSPORTS_ENV, restart_safe_env

from thermal_comp.cell.config import (MAX_DOMAIN_ID, NAME_RE, CellConfig, CellConfigError, NodeSpec,
                                      load_cell, parameters_file_text)


@dataclass(frozen=True)
class LaunchArgument:
    """A launch argument of ``cell.launch.py`` (``DeclareLaunchArgument``)."""

    name: str
    default: str | None          # None: required
    description: str


#: The arguments ``cell.launch.py`` declares, in the order ``ros2 launch -s`` lists them.
LAUNCH_ARGUMENTS = (
    LaunchArgument("cell_file", None, "cell YAML file: the nodes, their parameters, restart "
                   "policy and domain (thermal_comp.cell.config)"),
    LaunchArgument("namespace", "", "namespace of the cell's nodes, one level such as /line2_nmv "
                   "(empty: /CELL, the cell file's name)"),
    LaunchArgument("domain_id", "", "ROS_DOMAIN_ID of the cell's nodes, 0-232, 0-101 safe on Linux "
                   "(empty: the cell file's domain_id, else the launching environment's); with a "
                   "managed node it must be the launching environment's, where launch_ros's own "
                   "node sends the lifecycle transitions"),
)


@dataclass(frozen=True)
class NodeLaunch:
    """One node of a cell, in the terms of launch_ros ``Node`` / launch ``ExecuteProcess``."""

    name: str
    namespace: str
    package: str | None          # with executable: a launch_ros Node
    executable: str | None
    module: str                  # without package: run as ``python -m module``
    arguments: list[str]         # before --ros-args, as the launcher passes them
    parameters_yaml: str         # text of the node's ROS 2 parameters file
    env: dict[str, str] = field(default_factory=dict)
    respawn: bool = False
    respawn_delay_s: float = 0.0
    respawn_max_retries: int = -1
    lifecycle: bool = False          # a managed node: configure + activate after each start
    lifecycle_timeout_s: float = 30.0

    @property
    def full_name(self) -> str:
        return f"{self.namespace}/{self.name}"

    def node_arguments(self, python: str) -> tuple[str, list[str]]:
        """(executable, arguments) of a launch_ros ``Node`` for this node: the package's
        executable, or interpreter ``python`` with ``-m module`` for a node given by module."""
        if self.package is not None:
            return self.executable, list(self.arguments)
        return python, ["-m", self.module, *self.arguments]

    def ros_arguments(self, params_file: str) -> list[str]:
        """The ``--ros-args`` part of the command line, as ``thermal-comp launch`` builds it."""
        return ["--ros-args", "-r", f"__ns:={self.namespace}", "-r", f"__node:={self.name}",
                "--params-file", params_file]


def launch_arguments_text() -> str:
    """:data:`LAUNCH_ARGUMENTS` as ``ros2 launch thermal_comp cell.launch.py -s`` lists them."""
    lines = ["Arguments (pass arguments as '<name>:=<value>'):"]
    for a in LAUNCH_ARGUMENTS:
        lines += ["", f"    '{a.name}':", f"        {a.description}"]
        if a.default is not None:
            lines.append(f"        (default: '{a.default}')")
    return "\n".join(lines) + "\n"


def node_env(cell: CellConfig, node: NodeSpec) -> dict[str, str]:
    """Environment a node adds to the launching one: the cell's, the node's, the domain id, and
    UDP as the only DDS transport unless the cell or the launching environment names one (a
    respawned node must hear the graph: :mod:`thermal_comp_common.runtime.dds_transport`)."""
    env = {**cell.env, **node.env, "PYTHONUNBUFFERED": "1"}
    if not any(os.environ.get(k) for k in (TRANSPORTS_ENV, PROFILES_ENV)):
        env = restart_safe_env(env)
    if cell.domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(cell.domain_id)
    return env


def launch_plan(cell: CellConfig) -> list[NodeLaunch]:
    """The nodes a cell launch starts, in cell-file order."""
    plan = []
    for node in cell.nodes:
        by_executable = node.package is not None and node.executable is not None
        plan.append(NodeLaunch(
            name=node.name, namespace=cell.namespace,
            package=node.package if by_executable else None,
            executable=node.executable if by_executable else None,
            module=node.module, arguments=list(node.args),
            parameters_yaml=parameters_file_text(cell, node),
            env=node_env(cell, node),
            respawn=node.restart.enabled,
            # launch waits a fixed delay before each respawn; the launcher doubles it per crash.
            respawn_delay_s=node.restart.backoff_s if node.restart.enabled else 0.0,
            respawn_max_retries=node.restart.max_restarts if node.restart.enabled else -1,
            lifecycle=node.lifecycle, lifecycle_timeout_s=node.lifecycle_timeout_s))
    return plan


def _launch_value(name: str, value) -> str:
    if not isinstance(value, str):
        raise CellConfigError(f"launch argument {name}: expected text, got {value!r}")
    return value.strip()


def resolve_cell(cell_file: str, namespace: str = "", domain_id: str = "",
                 environ: Mapping[str, str] | None = None) -> CellConfig:
    """The cell ``cell.launch.py`` starts: the cell file with the launch arguments applied.

    CellConfigError (one line naming the argument and its value) for a bad value, and for a
    managed node on a domain other than the launching environment's: launch_ros sends lifecycle
    transitions from the launch process's own node, which would never reach it.
    """
    environ = os.environ if environ is None else environ
    cell = load_cell(_launch_value("cell_file", cell_file))
    ns = _launch_value("namespace", namespace)
    if ns:
        name = ns[1:] if ns.startswith("/") else ns
        if not NAME_RE.match(name):
            raise CellConfigError(f"launch argument namespace: expected one level such as /line2_nmv "
                                  f"(a letter, then letters, digits, _), got {namespace!r}")
        cell = dataclasses.replace(cell, cell=name)
    did = _launch_value("domain_id", domain_id)
    if did:
        if not did.isdigit() or not 0 <= int(did) <= MAX_DOMAIN_ID:
            raise CellConfigError(f"launch argument domain_id: expected an integer in "
                                  f"[0, {MAX_DOMAIN_ID}], got {domain_id!r}")
        cell = dataclasses.replace(cell, domain_id=int(did))
    own = environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    managed = [n.name for n in cell.nodes if n.lifecycle]
    if managed and cell.domain_id is not None and str(cell.domain_id) != own:
        raise CellConfigError(
            f"launch: cell {cell.namespace} runs on ROS_DOMAIN_ID {cell.domain_id}, this launch on "
            f"{own}: launch_ros drives the managed node(s) {managed} from its own node, which would "
            f"not reach them; start it as ROS_DOMAIN_ID={cell.domain_id} ros2 launch ...")
    return cell
