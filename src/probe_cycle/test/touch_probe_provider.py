"""Test-side TouchProbe provider: the ``twin/touch_probe`` service on the artefact model.

A stand-in for machine_sim in the probe tests. Its simulated clock starts at ``t0_s``,
and each request advances it by the request's ``duration_s``; the answer is taken at the
end of the move. The true errors are ``errors_before`` (JSON) until ``step_time_s`` and
``errors_after`` from then on. With ``answer_first`` N >= 0 it answers the first N requests
and leaves every later one pending for ever (a machine_sim that died mid-cycle), without
blocking its own executor. Run: ``python touch_probe_provider.py --ros-args -p ...``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time

import numpy as np
from rclpy.node import Node
from rclpy.task import Future

from thermal_comp_common.runtime.node_runtime import (SERVICE_TOUCH_PROBE, Param, declare_parameters,
                                       run_node, s_to_stamp)
from thermal_comp_msgs.srv import TouchProbe
from thermal_twin.machine.artefact_geometry import DEFAULT_GEOMETRY, touch_trigger_position


class TouchProbeProvider(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("touch_probe_provider", context=context, **kwargs)
        p = declare_parameters(self, [
            Param("errors_before", "{}", "true errors (JSON) before step_time_s"),
            Param("errors_after", "{}", "true errors (JSON) from step_time_s on"),
            Param("step_time_s", 1e9, "simulated instant of the error step, s"),
            Param("t0_s", 1000.0, "simulated time at start, s"),
            Param("axis_resolution_um", 1.0, "probe readout resolution, um", 0.0, 10.0),
            Param("seed", -1, "probe scatter seed; -1 = no scatter"),
            Param("answer_first", -1, "answer only this many requests, leave the rest pending "
                  "(-1 = answer all)"),
        ])
        self.answer_first = p["answer_first"]
        self._never = Future()          # never completed: what an unanswered request awaits
        self.before = json.loads(p["errors_before"])
        self.after = json.loads(p["errors_after"])
        self.step = p["step_time_s"]
        self.t = p["t0_s"]
        self.geometry = dataclasses.replace(
            DEFAULT_GEOMETRY, probe=dataclasses.replace(DEFAULT_GEOMETRY.probe,
                                                        axis_resolution_um=p["axis_resolution_um"]))
        self.rng = np.random.default_rng(p["seed"]) if p["seed"] >= 0 else None
        self.requests = 0
        self.create_service(TouchProbe, SERVICE_TOUCH_PROBE, self._serve)
        self.get_logger().info("touch probe provider ready")

    async def _serve(self, req, res):
        self.requests += 1
        if 0 <= self.answer_first < self.requests:
            self.get_logger().info(f"request {self.requests} left unanswered")
            await self._never
        self.t += req.duration_s
        errors = self.before if self.t < self.step else self.after
        try:
            ok, pos = touch_trigger_position(req.artefact, req.c_axis_deg, req.b_axis_deg,
                                             np.array(req.start_mm), np.array(req.direction),
                                             req.max_travel_mm, errors, {}, self.geometry,
                                             self.rng)
        except ValueError as exc:
            res.triggered, res.message = False, str(exc)
            pos = np.array(req.start_mm)
        else:
            res.triggered = bool(ok)
        res.trigger_position_mm = [float(v) for v in pos]
        res.stamp = s_to_stamp(self.t)
        return res


if __name__ == "__main__":
    sys.exit(run_node(TouchProbeProvider))


def stop_processes(procs) -> None:
    """Terminate test processes (kill after 10 s) and print their output (pytest shows it
    when a test failed)."""
    import subprocess
    for p in procs:
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        print(p.stdout.read())


def _answered_round_trip(ex, client, procs, end: float, per_try_s: float = 5.0) -> None:
    """Wait until the server answers this client, not only until the graph lists it.

    ``server_is_ready`` reads the graph; on a loaded machine Fast DDS may not yet have matched
    the server's response writers to this client's readers, and a goal sent then is answered
    into the void (CI saw a goal unanswered for 180 s). A cancel request and a result request
    for an unknown goal id are answered at once and change nothing on the server; they are
    repeated until both come back, so the first real goal travels a matched path.
    """
    import uuid
    import pytest
    from rclpy.action.client import ClientGoalHandle
    from unique_identifier_msgs.msg import UUID
    while True:
        probe = ClientGoalHandle(client, UUID(uuid=list(uuid.uuid4().bytes)), None)
        futs = [client._cancel_goal_async(probe), client._get_result_async(probe)]
        try_end = time.monotonic() + per_try_s
        while not all(f.done() for f in futs) and time.monotonic() < try_end:
            ex.spin_once(timeout_sec=0.05)
        if all(f.done() for f in futs):
            return
        for p in procs:
            if p.poll() is not None:
                pytest.fail(f"process exited early (code {p.returncode}): {p.args}")
        assert time.monotonic() < end, "probe_cycle action server never answered a request"


@contextlib.contextmanager
def probe_action_client(namespace: str, name: str, procs, wait_s: float = 120.0):
    """``(executor, client)``: a ProbeCycle action client in its own context, yielded once the
    server is ready; a test process that exits while waiting fails the test, naming it."""
    import pytest
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp_common.runtime.node_runtime import ACTION_PROBE_CYCLE
    from thermal_comp_msgs.action import ProbeCycle
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node(name, namespace=namespace, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    client = ActionClient(node, ProbeCycle, ACTION_PROBE_CYCLE)
    try:
        end = time.monotonic() + wait_s
        while not client.server_is_ready():
            for p in procs:
                if p.poll() is not None:
                    pytest.fail(f"process exited early (code {p.returncode}): {p.args}")
            assert time.monotonic() < end, "probe_cycle action server did not appear"
            ex.spin_once(timeout_sec=0.1)
        _answered_round_trip(ex, client, procs, end)
        yield ex, client
    finally:
        client.destroy()
        node.destroy_node()
        ex.shutdown()
        ctx.try_shutdown()
