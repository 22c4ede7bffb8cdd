"""The work of ``thermal-comp probe`` (:mod:`probe_cycle.probe_cli` parses the arguments): an action
client that runs one probing cycle on a running probe_cycle server, with a progress bar, and prints
the measured errors with their expanded uncertainty U (k=2)."""
from __future__ import annotations

import argparse
import sys
import time

import rclpy
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from thermal_comp_common.runtime.node_runtime import ACTION_PROBE_CYCLE
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import ThermalErrors


def run(args: argparse.Namespace, angles: list[float]) -> int:
    """Run the cycle the parsed arguments ask for; the exit code (0 succeeded, 1 failed or refused,
    2 no server answered)."""
    console = Console()
    ctx = rclpy.context.Context()
    rclpy.init(args=[], context=ctx)
    node = rclpy.create_node("probe_cli", namespace=args.namespace or None, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    client = ActionClient(node, ProbeCycle, ACTION_PROBE_CYCLE)
    try:
        if not _wait_for_server(client, ex, args):
            return 2
        result = _run_goal(client, ex, _goal(args, angles), args.deadline, console)
        if result is None:
            return 1
        if not result.success:
            console.print(f"[red]probe cycle failed:[/red] {result.message}")
            return 1
        _print_result(console, result)
        return 0
    finally:
        client.destroy()
        node.destroy_node()
        ex.shutdown()
        rclpy.shutdown(context=ctx)


def _wait_for_server(client: ActionClient, ex: SingleThreadedExecutor, args) -> bool:
    end = time.monotonic() + args.wait
    while not client.server_is_ready():
        if time.monotonic() > end:
            print(f"thermal-comp probe: no '{ACTION_PROBE_CYCLE}' action server answered "
                  f"within {args.wait:g} s (namespace '{args.namespace or '/'}')",
                  file=sys.stderr)
            return False
        ex.spin_once(timeout_sec=0.1)
    return True


def _goal(args, angles: list[float]) -> ProbeCycle.Goal:
    goal = ProbeCycle.Goal()
    goal.artefact = (ProbeCycle.Goal.ARTEFACT_GUIDE_BUSH if args.guide_bush
                     else ProbeCycle.Goal.ARTEFACT_SPHERE)
    goal.set_reference = args.set_reference
    goal.points_per_indexing = args.points
    goal.c_angles_deg = angles
    goal.timeout_s = args.timeout
    return goal


def _run_goal(client: ActionClient, ex: SingleThreadedExecutor, goal, deadline_s: float,
              console: Console):
    """The action's result, or None (message printed) if refused or not answered in time."""
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("probing", total=None)

        def on_feedback(msg):
            fb = msg.feedback
            progress.update(task, total=fb.points_total, completed=fb.points_done,
                            description=fb.stage)

        send = client.send_goal_async(goal, feedback_callback=on_feedback)
        deadline = time.monotonic() + deadline_s
        while not send.done():
            if time.monotonic() > deadline:
                print("thermal-comp probe: the goal was not answered", file=sys.stderr)
                return None
            ex.spin_once(timeout_sec=0.1)
        handle = send.result()
        if not handle.accepted:
            print("thermal-comp probe: goal refused (a cycle is already running?)",
                  file=sys.stderr)
            return None
        res_future = handle.get_result_async()
        while not res_future.done():
            if time.monotonic() > deadline:
                handle.cancel_goal_async()
                print(f"thermal-comp probe: no result within {deadline_s:g} s; "
                      "cancel sent", file=sys.stderr)
                return None
            ex.spin_once(timeout_sec=0.1)
    return res_future.result().result


def _print_result(console: Console, result) -> None:
    e = result.errors
    table = Table(title=f"{e.model_kind}: {result.message.split(':')[0]}")
    for col in ("component", "value", "U (k=2)", "unit"):
        table.add_column(col, justify="left" if col in ("component", "unit") else "right")
    for name, v, u, unit in zip(e.component_names, e.values, e.uncertainties, e.units):
        table.add_row(name, f"{v:+.2f}", f"{2 * u:.2f}",
                      "um/m" if unit == ThermalErrors.UNIT_UM_PER_M else "um")
    console.print(table)
    console.print(f"duration {result.duration_s:.1f} s, fit RMS "
                  f"{result.fit_residual_rms_um:.2f} um, 360/0 check "
                  f"{result.repeatability_check_um:.2f} um")
