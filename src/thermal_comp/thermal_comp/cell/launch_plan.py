"""What `ros2 launch thermal_comp cell.launch.py cell_file:=CELL.yaml` starts, as plain data.

The launch file (``launch/cell.launch.py``) turns each :class:`NodeLaunch` into a launch_ros
``Node`` (or an ``ExecuteProcess`` for a node given by ``module``). It is computed here from a
parsed cell file, with the same parameters-file text, namespace, node name, arguments and
environment as ``thermal-comp launch`` (``launcher.py``), so the two ways to start a cell are
equivalent by construction. Kept free of ``launch`` imports: launch has no wheels for this
venv, and the plan is tested as a pure function of the cell file.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from thermal_comp.cell.config import CellConfig, NodeSpec, parameters_file_text


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
    lifecycle: bool = False          # a managed node: configure + activate after its start
    lifecycle_timeout_s: float = 30.0

    def lifecycle_command(self, python: str, transitions=("configure", "activate")) -> list[str]:
        """The driver ``thermal-comp launch`` runs for a managed node (same deadline per transition)."""
        return [python, "-m", "thermal_comp.cell.lifecycle_driver", "--timeout", f"{self.lifecycle_timeout_s:g}",
                f"{self.namespace}/{self.name}", *transitions]

    def ros_arguments(self, params_file: str) -> list[str]:
        """The ``--ros-args`` part of the command line, as ``thermal-comp launch`` builds it."""
        return ["--ros-args", "-r", f"__ns:={self.namespace}", "-r", f"__node:={self.name}",
                "--params-file", params_file]


def node_env(cell: CellConfig, node: NodeSpec) -> dict[str, str]:
    """Environment a node adds to the launching one: the cell's, the node's, the domain id."""
    env = {**cell.env, **node.env, "PYTHONUNBUFFERED": "1"}
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
