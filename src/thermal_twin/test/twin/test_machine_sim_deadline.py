"""Nothing hangs silently: machine_sim names a late or inconsistent lock-step participant, with the
instant, on the log and /diagnostics, then stops the graph (exit code 3) or goes on (on_late)."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.ros]

HOURS = 0.1     # 7 instants of 60 s


def _spawn(participant: str, deadline_s: float, on_late: str = "stop"):
    return subprocess.Popen(
        [sys.executable, "-m", "thermal_twin.machine_sim_node", "--ros-args",
         "-r", "__node:=machine_sim", "-p", f"hours:={HOURS}", "-p", "shutdown_when_done:=true",
         "-p", f"lockstep_participants:=['{participant}']", "-p", f"lockstep_deadline_s:={deadline_s}",
         "-p", f"on_late:={on_late}"],
        env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


class _Participant:
    """A test participant: acknowledges what ``ack(t)`` says, records /diagnostics."""

    def __init__(self, name: str, ack):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from thermal_comp_common.runtime.diagnostics import DIAGNOSTICS_QOS, TOPIC_DIAGNOSTICS
        from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, SENSOR_QOS, TOPIC_MACHINE_STATE,
                                                      TOPIC_SIM_SYNC, s_to_stamp, stamp_to_s)
        from thermal_comp_msgs.msg import MachineState, SimSync
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(name, context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.seen: list[float] = []
        self.diags: list = []
        pub = self.node.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)

        def on_state(m):
            t = stamp_to_s(m.header.stamp)
            self.seen.append(t)
            a = ack(t)
            if a is not None:
                pub.publish(SimSync(node_name=name, processed_until=s_to_stamp(a)))
        self.node.create_subscription(MachineState, TOPIC_MACHINE_STATE, on_state, SENSOR_QOS)
        self.node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self.diags.append, DIAGNOSTICS_QOS)

    def run_until_exit(self, proc, timeout_s: float = 60.0) -> tuple[int, str]:
        end = time.monotonic() + timeout_s
        while proc.poll() is None and time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.05)
        if proc.poll() is None:
            proc.kill()
        out = proc.communicate()[0]
        for _ in range(10):
            self.ex.spin_once(timeout_sec=0.02)
        return proc.returncode, out

    def lockstep_statuses(self):
        return [s for a in self.diags for s in a.status if s.name == "machine_sim: lock-step"]

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()


def test_absent_participant_stops_the_graph_naming_it():
    proc = _spawn("ghost_model", deadline_s=1.0)
    try:
        out = proc.communicate(timeout=60)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 3, out
    line = [x for x in out.splitlines() if "lock-step:" in x and "ERROR" in x]
    assert line and "ghost_model has not joined" in line[0] and "t = 0 s" in line[0], out


def test_participant_that_stops_acknowledging_is_named_with_the_instant():
    from diagnostic_msgs.msg import DiagnosticStatus
    part = _Participant("slow_model", ack=lambda t: t if t < 120.0 else None)
    proc = _spawn("slow_model", deadline_s=5.0)
    try:
        code, out = part.run_until_exit(proc)
        assert code == 3, out
        assert "slow_model has not acknowledged it for instant t = 120 s" in out, out
        assert sorted(set(part.seen))[:3] == [0.0, 60.0, 120.0]
        errors = [s for s in part.lockstep_statuses() if s.level == DiagnosticStatus.ERROR]
        assert errors and "slow_model" in errors[-1].message
        assert {kv.key: kv.value for kv in errors[-1].values}["instant_s"] == "120.0"
    finally:
        part.close()


def test_forged_acknowledgement_ahead_of_the_graph_is_ignored_and_the_run_goes_on():
    # a forged acknowledgement (or a state of another run) of an instant the graph never published:
    # named, counted, on /diagnostics; the honest participant's acknowledgements carry the run
    import rclpy
    from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, SENSOR_QOS, TOPIC_MACHINE_STATE,
                                                          TOPIC_SIM_SYNC, s_to_stamp)
    from thermal_comp_msgs.msg import MachineState, SimSync
    part = _Participant("honest_model", ack=lambda t: t)
    forger = rclpy.create_node("forger", context=part.ctx)
    part.ex.add_node(forger)
    forged = forger.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
    forger.create_subscription(   # every instant, a forged acknowledgement 10^7 s ahead
        MachineState, TOPIC_MACHINE_STATE,
        lambda m: forged.publish(SimSync(node_name="honest_model", processed_until=s_to_stamp(1.0e7))), SENSOR_QOS)
    proc = _spawn("honest_model", deadline_s=30.0)
    try:
        code, out = part.run_until_exit(proc)
        assert code == 0, out
        ignored = [x for x in out.splitlines() if "ignored" in x and "'honest_model'" in x]
        assert ignored and "forger" in ignored[0] and "10000000.0" in ignored[0], out
        assert sorted(set(part.seen))[-1] == pytest.approx(HOURS * 3600.0)
        stamps = [s for a in part.diags for s in a.status if s.name == "machine_sim: stamps"]
        values = {kv.key: kv.value for kv in stamps[-1].values}
        assert int(values["acks_refused"]) >= 1, values
    finally:
        forger.destroy_node()
        part.close()


def test_drop_policy_goes_on_without_the_late_participant():
    from diagnostic_msgs.msg import DiagnosticStatus
    part = _Participant("flaky_viewer", ack=lambda t: t if t < 60.0 else None)
    proc = _spawn("flaky_viewer", deadline_s=5.0, on_late="drop")
    try:
        code, out = part.run_until_exit(proc)
        assert code == 0, out
        assert "flaky_viewer has not acknowledged it for instant t = 60 s" in out
        assert "dropped from the lock-step" in out
        assert sorted(set(part.seen))[-1] == pytest.approx(HOURS * 3600.0)
        assert any(s.level == DiagnosticStatus.WARN and "dropped flaky_viewer" in s.message
                   for s in part.lockstep_statuses())
    finally:
        part.close()
