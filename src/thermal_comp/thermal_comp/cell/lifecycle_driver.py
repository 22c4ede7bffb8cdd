"""Drive managed (lifecycle) nodes through transitions, each with a deadline.

``python -m thermal_comp.cell.lifecycle_driver --timeout 20 /cell/bridge configure activate``
asks ``/cell/bridge/change_state`` for each transition in order and exits 0 when every one
succeeded. It exits 1 with one line naming the node and the transition when a transition is
refused (the node's callback failed), when the node's service does not appear, or when an
answer does not come within the deadline: nothing waits forever. The launcher runs it in the
cell's environment (ROS_DOMAIN_ID), so one launcher can drive cells in several domains.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")


class TransitionError(RuntimeError):
    """A transition failed or timed out (the message names the node and the transition)."""


def _transition_id(name: str) -> int:
    return {"configure": Transition.TRANSITION_CONFIGURE,
            "activate": Transition.TRANSITION_ACTIVATE,
            "deactivate": Transition.TRANSITION_DEACTIVATE,
            "cleanup": Transition.TRANSITION_CLEANUP,
            "shutdown": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN}[name]


def _spin_until(executor, done, timeout_s: float, error: str) -> None:
    """Spin until ``done()``; TransitionError(``error``) after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > deadline:
            raise TransitionError(error)
        executor.spin_once(timeout_sec=0.05)


def drive(node, executor, target: str, transitions: list[str], timeout_s: float) -> None:
    """Run ``transitions`` on lifecycle node ``target`` (full name) from rclpy ``node``."""
    client = node.create_client(ChangeState, f"{target}/change_state")
    try:
        _spin_until(executor, client.service_is_ready, timeout_s,
                    f"{target}: no lifecycle service {target}/change_state within {timeout_s:g} s "
                    "(not started, or not a managed node)")
        for name in transitions:
            request = ChangeState.Request()
            request.transition.id = _transition_id(name)
            future = client.call_async(request)
            _spin_until(executor, future.done, timeout_s,
                        f"{target}: transition '{name}' did not answer within {timeout_s:g} s")
            if not future.result().success:
                raise TransitionError(f"{target}: transition '{name}' failed (see the node's log)")
    finally:
        node.destroy_client(client)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m thermal_comp.cell.lifecycle_driver",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("node", help="full node name, e.g. /cell_a/bridge")
    ap.add_argument("transitions", nargs="+", choices=TRANSITIONS)
    ap.add_argument("--timeout", type=float, default=20.0, help="deadline per step, s")
    args = ap.parse_args(argv)
    context = rclpy.context.Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"lifecycle_driver_{os.getpid()}", context=context,
                             start_parameter_services=False, enable_rosout=False)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        drive(node, executor, args.node, args.transitions, args.timeout)
        print(f"{args.node}: {' '.join(args.transitions)}: done", flush=True)
        return 0
    except TransitionError as exc:
        print(f"lifecycle: {exc}", file=sys.stderr, flush=True)
        return 1
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
