"""Launch one machine cell from its cell file: ``ros2 launch thermal_comp cell.launch.py cell_file:=CELL.yaml``.

Arguments (``ros2 launch thermal_comp cell.launch.py -s``): ``cell_file`` (required),
``namespace`` and ``domain_id`` (see ``thermal_comp.cell.launch_plan.LAUNCH_ARGUMENTS``).
The same nodes, namespace, parameters, arguments and ROS_DOMAIN_ID as
``thermal-comp launch CELL.yaml``: both read the file with ``thermal_comp.cell.config`` and the
node list comes from ``thermal_comp.cell.launch_plan.launch_plan``. The node list is known only
once ``cell_file`` is, so one ``OpaqueFunction`` reads the file at launch time; every node is a
launch_ros ``Node``. A managed node (the CNC bridge) is a ``LifecycleNode`` driven by launch's
events: the first start of its process emits ``ChangeState`` configure; its ``OnStateTransition``
to inactive emits activate; a respawned one stays unconfigured (writes nothing); a failed
configure or activate, or no active state within three ``lifecycle_timeout_s`` of the start, is
one error line and ends the launch (``Shutdown``), as ``thermal-comp launch`` stops on it. A crashed node is respawned after a
fixed ``backoff_s`` (the launcher doubles it per crash); a node that crashes and is not
respawned ends the launch. A second launch of a running cell (same namespace and domain) is
refused with a line naming the running one (``thermal_comp.cell.cell_lock``).
"""
import os
import pathlib
import sys
import tempfile

from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, EmitEvent, LogInfo, OpaqueFunction,
                            RegisterEventHandler, Shutdown, TimerAction)
from launch.event_handlers import OnProcessExit, OnProcessStart
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from lifecycle_msgs.msg import Transition

from thermal_comp.cell.cell_lock import acquire_cell_lock
from thermal_comp.cell.launch_plan import LAUNCH_ARGUMENTS, launch_plan, resolve_cell

_LOCKS = []   # held for the life of the launch process: one cell, one owner


def _change_state(node, transition_id):
    return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(node),
                                       transition_id=transition_id))


def _lifecycle_events(node, spec):
    """configure at the first start of the process, activate once inactive; a failed step, or
    no active state within three lifecycle deadlines of the start (the launcher's three: the
    service appearing, configure, activate), ends the launch. A respawned managed node stays
    unconfigured (writes nothing): launch_ros would send its configure while the graph still
    lists the crashed process's change_state service, and waits for the answer without a
    deadline; a lost request was seen in the tests."""
    full_name, deadline_s = spec.full_name, 3 * spec.lifecycle_timeout_s
    active = []

    def failed(step, start, goal):
        return RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=node, start_state=start, goal_state=goal,
            entities=[LogInfo(msg=f"ERROR {full_name}: transition '{step}' failed (see the node's log); "
                                  "stopping the cell"),
                      Shutdown(reason=f"{full_name}: {step} failed")]))

    def check_deadline(context):
        if active or context.is_shutdown:
            return None
        return [LogInfo(msg=f"ERROR {full_name}: not active within {deadline_s:g} s of its start "
                            "(configure and activate); stopping the cell"),
                Shutdown(reason=f"{full_name}: not active within {deadline_s:g} s")]

    return [
        RegisterEventHandler(OnProcessStart(
            target_action=node, handle_once=True,
            on_start=[_change_state(node, Transition.TRANSITION_CONFIGURE),
                      TimerAction(period=deadline_s, actions=[OpaqueFunction(function=check_deadline)])])),
        RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=node, start_state="configuring", goal_state="inactive",
            entities=[_change_state(node, Transition.TRANSITION_ACTIVATE)])),
        RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=node, start_state="activating", goal_state="active",
            entities=[LogInfo(msg=f"{full_name}: configured and active"),
                      OpaqueFunction(function=lambda context: active.append(True))])),
        failed("configure", "configuring", "unconfigured"),
        failed("activate", "activating", "inactive"),
    ]


def _end_on_crash(node, spec):
    """A node that crashes and is not respawned ends the launch (the cell cannot go on).
    launch respawns the k-th exit of a process while k <= respawn_max_retries (any k if < 0)."""
    exits = [0]

    def on_exit(event, context):
        exits[0] += 1
        respawned = spec.respawn and (spec.respawn_max_retries < 0 or exits[0] <= spec.respawn_max_retries)
        if context.is_shutdown or event.returncode == 0 or respawned:
            return None
        return [LogInfo(msg=f"{spec.full_name} exited with code {event.returncode} and is not "
                            "restarted: the cell cannot go on without it; stopping every node"),
                Shutdown(reason=f"{spec.full_name} exited with code {event.returncode}")]
    return RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit))


def _cell_actions(context):
    cell = resolve_cell(*(LaunchConfiguration(a.name).perform(context) for a in LAUNCH_ARGUMENTS))
    domain = cell.domain_id if cell.domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID") or 0)
    lock = acquire_cell_lock(domain, cell.namespace)   # CellLockError names the running launch
    if lock.warning:
        print(f"[launch] {lock.warning}", file=sys.stderr, flush=True)
    _LOCKS.append(lock)
    params_dir = pathlib.Path(tempfile.mkdtemp(prefix=f"thermal_comp_{cell.cell}_"))
    actions = []
    for spec in launch_plan(cell):
        params_file = params_dir / f"{spec.name}.params.yaml"
        params_file.write_text(spec.parameters_yaml)
        executable, arguments = spec.node_arguments(sys.executable)
        kind = LifecycleNode if spec.lifecycle else Node
        node = kind(package=spec.package, executable=executable, name=spec.name,
                    namespace=spec.namespace, arguments=arguments, parameters=[str(params_file)],
                    additional_env=spec.env, output="screen", respawn=spec.respawn,
                    respawn_delay=spec.respawn_delay_s, respawn_max_retries=spec.respawn_max_retries)
        actions.append(node)
        if spec.lifecycle:
            actions += _lifecycle_events(node, spec)
        actions.append(_end_on_crash(node, spec))
    return actions


def generate_launch_description():
    return LaunchDescription([
        *(DeclareLaunchArgument(a.name, description=a.description) if a.default is None else
          DeclareLaunchArgument(a.name, default_value=a.default, description=a.description)
          for a in LAUNCH_ARGUMENTS),
        OpaqueFunction(function=_cell_actions),
    ])
