"""Simulated time for a node spun by a MultiThreadedExecutor, from a private single-threaded one.

With ``use_sim_time`` rclpy subscribes the node to ``/clock`` in the node's own executor. In
probe_cycle's MultiThreadedExecutor (needed so a cancel or a stop reaches a cycle in flight)
that subscription keeps the main thread yielding clock handlers (hundreds of thousands per
minute with a few thousand ``/clock`` messages): it spins one core and, holding the GIL, delays
the touch-probe client's thread, so a millisecond service round trip can take seconds
(figures: docs/cnc_bridge.md, "Quiet figures").

:class:`SimClockFollower` keeps ``use_sim_time`` applied: the node's clock still follows
``/clock``, but through a private node (same context and namespace) spun by its own
single-threaded executor thread, as the touch-probe client is. ``use_sim_time`` is then fixed
for the node's life: a later change is refused with a reason, never accepted and ignored.
"""
from __future__ import annotations

import threading

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time_source import TimeSource


class SimClockFollower:
    """Move ``node``'s ``/clock`` subscription to a private node on its own executor thread."""

    def __init__(self, node: Node):
        own = getattr(node, "_time_source", None)    # rclpy keeps no public handle on it
        if own is None:
            raise RuntimeError("use_sim_time: this rclpy keeps no time source on the node; "
                               "cannot move its /clock subscription")
        own.detach_node()                            # the node's own /clock subscription goes
        self.node = rclpy.create_node(f"{node.get_name()}_clock", namespace=node.get_namespace(),
                                      context=node.context, use_global_arguments=False,
                                      parameter_overrides=[Parameter("use_sim_time", value=True)])
        self.time_source = TimeSource(node=self.node)
        self.time_source.attach_clock(node.get_clock())
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name="sim-clock", daemon=True)
        self._thread.start()
        node.add_on_set_parameters_callback(_refuse_sim_time_change)

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:          # the context shut down under it (the node's stop)
            pass

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=1.0)
        self._thread.join(timeout=2.0)
        self.time_source.detach_node()
        self.node.destroy_node()


def _refuse_sim_time_change(params: list[Parameter]) -> SetParametersResult:
    for p in params:
        if p.name == "use_sim_time":
            return SetParametersResult(successful=False, reason="use_sim_time: set at start-up only "
                                       "(the node's clock follows /clock through a private node)")
    return SetParametersResult(successful=True)
