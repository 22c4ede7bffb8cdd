"""Launch one machine cell from its cell file: ``ros2 launch thermal_comp cell.launch.py cell_file:=CELL.yaml``.

The same nodes, namespace, parameters, arguments and ROS_DOMAIN_ID as
``thermal-comp launch CELL.yaml``: both read the file with ``thermal_comp.cell.config`` and the
node list comes from ``thermal_comp.cell.launch_plan.launch_plan``. Differences that launch imposes:
a crashed node is respawned after a fixed ``backoff_s`` (the launcher doubles it per crash), and a
managed (lifecycle) node is configured and activated once after its start by the same driver the
launcher runs (``thermal_comp.cell.lifecycle_driver``, one deadline per transition); after a respawn it
stays unconfigured (writes nothing) and the lock-step deadline names it.
"""
import pathlib
import sys
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from thermal_comp.cell.config import load_cell
from thermal_comp.cell.launch_plan import launch_plan


def _cell_actions(context):
    cell = load_cell(LaunchConfiguration("cell_file").perform(context))
    params_dir = pathlib.Path(tempfile.mkdtemp(prefix=f"thermal_comp_{cell.cell}_"))
    actions = []
    for spec in launch_plan(cell):
        params_file = params_dir / f"{spec.name}.params.yaml"
        params_file.write_text(spec.parameters_yaml)
        respawn = {"respawn": spec.respawn, "respawn_delay": spec.respawn_delay_s,
                   "respawn_max_retries": spec.respawn_max_retries}
        if spec.package is not None:
            actions.append(Node(
                package=spec.package, executable=spec.executable, name=spec.name,
                namespace=spec.namespace, arguments=spec.arguments, parameters=[str(params_file)],
                additional_env=spec.env, output="screen", **respawn))
        else:
            actions.append(ExecuteProcess(
                cmd=[sys.executable, "-m", spec.module, *spec.arguments,
                     *spec.ros_arguments(str(params_file))],
                name=f"{cell.cell}_{spec.name}", additional_env=spec.env, output="screen", **respawn))
        if spec.lifecycle:
            actions.append(ExecuteProcess(cmd=spec.lifecycle_command(sys.executable),
                                          name=f"{cell.cell}_{spec.name}_lifecycle",
                                          additional_env=spec.env, output="screen"))
    return actions


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("cell_file", description="cell YAML (see thermal_comp.cell.config)"),
        OpaqueFunction(function=_cell_actions),
    ])
