"""The probe_cycle server puts its last cycle's result, cycles run and failures on
/diagnostics (in process: the execute callback is called with a stand-in goal handle and a
backend answering from the artefact model without errors, or failing)."""
from __future__ import annotations

import numpy as np
import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)
from thermal_comp_msgs.action import ProbeCycle  # noqa: E402
from thermal_twin.machine.artefact_geometry import touch_trigger_position  # noqa: E402
from probe_cycle.probe_backend import ProbeBackend, ProbeBackendError, TouchReply  # noqa: E402

pytestmark = [pytest.mark.ros]


class _PerfectArtefact(ProbeBackend):
    """Touches on the artefact model of a machine without thermal errors."""

    name = "perfect"

    def __init__(self, fail: bool = False):
        self.t, self.fail = 1000.0, fail

    def touch(self, move):
        if self.fail:
            raise ProbeBackendError("no answer from the CNC")
        self.t += move.duration_s
        triggered, pos = touch_trigger_position(
            int(move.artefact), float(move.c_axis_deg), float(move.b_axis_deg), np.asarray(move.start_mm, float),
            np.asarray(move.direction, float), float(move.max_travel_mm), {}, {}, rng=None)
        return TouchReply(bool(triggered), np.asarray(pos, float), self.t, "")

    def close(self) -> None:
        pass


class _GoalHandle:
    def __init__(self, set_reference: bool):
        self.request = ProbeCycle.Goal(artefact=ProbeCycle.Goal.ARTEFACT_SPHERE, set_reference=set_reference)
        self.is_cancel_requested = False
        self.outcome = None

    def publish_feedback(self, fb):
        pass

    def succeed(self):
        self.outcome = "succeeded"

    def abort(self):
        self.outcome = "aborted"

    def canceled(self):
        self.outcome = "canceled"


def test_last_cycle_and_failures_are_on_diagnostics():
    from probe_cycle.probe_cycle_node import ProbeCycleNode
    ctx = rclpy.context.Context()
    rclpy.init(args=["x", "--ros-args", "-p", "backend:=twin"], context=ctx)
    node = ProbeCycleNode(context=ctx)
    try:
        def status():
            s = next(s for s in node.diag.statuses() if s.name.endswith(": probe cycle"))
            return s.level, s.message, {kv.key: kv.value for kv in s.values}

        assert status()[:2] == (b"\x00", "no cycle yet")
        node.backend = _PerfectArtefact()
        for ref in (True, False):
            h = _GoalHandle(ref)
            assert node._execute(h).success and h.outcome == "succeeded"
        level, message, values = status()
        assert level == b"\x00" and message.startswith("last cycle ok: ")
        assert (values["cycles"], values["failures"]) == ("2", "0")
        node.backend = _PerfectArtefact(fail=True)
        h = _GoalHandle(False)
        assert not node._execute(h).success and h.outcome == "aborted"
        level, message, values = status()
        assert level == b"\x01" and "FAILED" in message and "no answer from the CNC" in message
        assert (values["cycles"], values["failures"]) == ("3", "1")
    finally:
        node.destroy_node()
        ctx.try_shutdown()
