"""Test node: a ProbeCycle action server with scripted behaviour, for interface tests.

The goal's ``points_per_indexing`` is the number of feedback steps; each step waits until the
client has acknowledged the previous feedback by calling the `~/next` trigger service, so the
exchange is deterministic without timing. ``points_per_indexing == 0`` runs until cancelled.
"""
from __future__ import annotations

import sys
import threading

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger

from thermal_comp_common.runtime.node_runtime import ACTION_PROBE_CYCLE, run_node
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import ThermalErrors


class ScriptedProbeServer(Node):
    def __init__(self, context=None):
        super().__init__("scripted_probe_server", context=context)
        group = ReentrantCallbackGroup()
        self._step = threading.Semaphore(0)
        self.create_service(Trigger, "~/next", self.on_next, callback_group=group)
        ActionServer(self, ProbeCycle, ACTION_PROBE_CYCLE, execute_callback=self.execute,
                     goal_callback=lambda g: GoalResponse.ACCEPT,
                     cancel_callback=lambda h: CancelResponse.ACCEPT, callback_group=group)

    def on_next(self, req, resp):
        self._step.release()
        resp.success = True
        return resp

    def execute(self, goal_handle):
        goal = goal_handle.request
        total = goal.points_per_indexing
        fb = ProbeCycle.Feedback()
        fb.points_total = total
        i = 0
        while total == 0 or i < total:
            while not self._step.acquire(timeout=0.05):
                if goal_handle.is_cancel_requested:
                    goal_handle.canceled()
                    return ProbeCycle.Result(success=False, message=f"cancelled after {i} points")
            i += 1
            fb.points_done = i
            fb.stage = f"point {i}"
            goal_handle.publish_feedback(fb)
        res = ProbeCycle.Result()
        res.success = True
        res.duration_s = 95.0
        res.message = f"{i} points"
        res.errors.source = ThermalErrors.SOURCE_MEASURED
        res.errors.component_names = ["E_X0C", "E_A0C"]
        res.errors.values = [1.5, -2.0]
        res.errors.units = [ThermalErrors.UNIT_UM, ThermalErrors.UNIT_UM_PER_M]
        res.errors.uncertainties = [0.2, 1.2]
        goal_handle.succeed()
        return res


def main(args=None):
    return run_node(ScriptedProbeServer, args, multi_threaded=True, num_threads=3)


if __name__ == "__main__":
    sys.exit(main())
