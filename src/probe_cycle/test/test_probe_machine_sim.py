"""The ProbeCycle action against the real machine_sim node, in lock-step simulated time.

The test node is machine_sim's lock-step participant. It lets the machine run for 15 min
(C axis turning, warming up), holds the clock (no acknowledgement) while a reference cycle
runs, lets it run one more hour, and holds it again for a second cycle. While the clock is
held, only the probe's touch requests advance simulated time. The results over ROS must
equal the same sequence run offline on the twin's pure core (ScenarioRunner, with idle()
per move as machine_sim does). The measured change must agree with the twin's ground
truth within the reported uncertainty.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)
from action_msgs.msg import GoalStatus  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from thermal_comp_common.runtime.node_runtime import (ACTION_PROBE_CYCLE, EVENT_QOS, SENSOR_QOS,  # noqa: E402
                                       TOPIC_SIM_SYNC, TOPIC_TWIN_SENSORS, s_to_stamp,
                                       stamp_to_s)
from thermal_comp_msgs.action import ProbeCycle  # noqa: E402
from thermal_comp_msgs.msg import SimSync, TemperatureArray  # noqa: E402
from thermal_twin.machine.artefact_geometry import (DEFAULT_GEOMETRY, SPHERE_COMPONENTS,  # noqa: E402
                                            touch_trigger_position)
from probe_cycle.probe_backend import ProbeBackend, TouchReply  # noqa: E402
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine  # noqa: E402
from touch_probe_provider import stop_processes

pytestmark = [pytest.mark.slow, pytest.mark.ros]

MACHINE, SCENARIO, HOURS, SEED = "nmv5000", "talc-178h-dry", 1.5, 4
WARM_UP_STEPS, BETWEEN_STEPS = 15, 60     # 60 s instants: reference at 15 min, next 1 h later
PARTICIPANT = "probe_test_participant"
NS = "/probe_machine_sim_test"     # own namespace: nothing left over from another test answers


class OfflineTwin(ProbeBackend):
    """What machine_sim does per TouchProbe request, on the pure ScenarioRunner."""

    name = "offline_twin"

    def __init__(self):
        from thermal_twin.machine.schema import load_machine
        from thermal_twin.sim.scenario_runner import ScenarioRunner
        from thermal_twin.sim.scenarios import make_timeline
        m = load_machine(MACHINE)
        self.runner = ScenarioRunner(m, make_timeline(m.name, SCENARIO, hours=HOURS, seed=SEED),
                                     seed=SEED)
        self.truth = []      # true errors at every touch

    def touch(self, move):
        r = self.runner
        r.busy_probing = True
        r.idle(move.duration_s)
        errors = {k[:-3] if k.endswith("_um") else k: v for k, v in r.errors().items()}
        self.truth.append(errors)
        ok, pos = touch_trigger_position(move.artefact, move.c_axis_deg, move.b_axis_deg,
                                         np.asarray(move.start_mm), np.asarray(move.direction),
                                         move.max_travel_mm, errors, {}, DEFAULT_GEOMETRY, None)
        r.resume()
        r.busy_probing = False
        return TouchReply(bool(ok), np.asarray(pos, dtype=float), r.t_s)


def _spawn(args):
    return subprocess.Popen([sys.executable, *args], env=dict(os.environ),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_probe_cycles_on_machine_sim_equal_the_offline_twin(ros_domain_id):
    procs = [
        _spawn(["-m", "thermal_twin.machine_sim_node", "--ros-args",
                "-p", f"machine:={MACHINE}", "-p", f"scenario:={SCENARIO}",
                "-p", f"hours:={HOURS}", "-p", f"seed:={SEED}",
                "-p", f"lockstep_participants:=['{PARTICIPANT}']", "-p", "probe_noise:=false",
                "-r", f"__ns:={NS}"]),
        _spawn(["-m", "probe_cycle.probe_cycle_node", "--ros-args", "-p", "backend:=twin",
                "-p", "use_sim_time:=true", "-r", f"__ns:={NS}"]),
    ]
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node(PARTICIPANT, namespace=NS, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    seen = []                        # instants published by machine_sim, in order

    def on_readings(m):
        t = stamp_to_s(m.header.stamp)
        if not seen or t > seen[-1]:
            seen.append(t)
    node.create_subscription(TemperatureArray, TOPIC_TWIN_SENSORS, on_readings, SENSOR_QOS)
    sync = node.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
    client = ActionClient(node, ProbeCycle, ACTION_PROBE_CYCLE)

    def spin_until(cond, timeout_s, what):
        end = time.monotonic() + timeout_s
        while not cond():
            for p in procs:
                if p.poll() is not None:
                    pytest.fail(f"a process exited while waiting for {what}: {p.stdout.read()}")
            assert time.monotonic() < end, f"timed out waiting for {what}"
            ex.spin_once(timeout_sec=0.05)

    def run(goal):
        fut = client.send_goal_async(goal)
        spin_until(fut.done, 60.0, "goal response")
        res = fut.result().get_result_async()
        spin_until(res.done, 180.0, "probe result")
        return res.result()

    def advance(steps):
        for _ in range(steps):
            n = len(seen)
            sync.publish(SimSync(node_name=PARTICIPANT, processed_until=s_to_stamp(seen[-1])))
            spin_until(lambda: len(seen) > n, 60.0, "the next instant")

    try:
        spin_until(lambda: bool(seen) and client.server_is_ready(), 120.0,
                   "machine_sim's first instant and the action server")
        advance(WARM_UP_STEPS)
        ref = run(ProbeCycle.Goal(artefact=ProbeCycle.Goal.ARTEFACT_SPHERE, set_reference=True))
        advance(BETWEEN_STEPS)
        second = run(ProbeCycle.Goal(artefact=ProbeCycle.Goal.ARTEFACT_SPHERE))
    finally:
        client.destroy()
        node.destroy_node()
        ex.shutdown()
        rclpy.shutdown(context=ctx)
        stop_processes(procs)

    assert ref.status == GoalStatus.STATUS_SUCCEEDED, ref.result.message
    assert second.status == GoalStatus.STATUS_SUCCEEDED, second.result.message

    offline = OfflineTwin()
    engine = ProbeCycleEngine(DEFAULT_GEOMETRY)
    for _ in range(WARM_UP_STEPS):
        offline.runner.step()
    off_ref = engine.run(GoalSpec(set_reference=True), offline)
    for _ in range(BETWEEN_STEPS):
        offline.runner.step()
    off_second = engine.run(GoalSpec(), offline)
    assert off_ref.success and off_second.success

    e = second.result.errors
    np.testing.assert_allclose(e.values, off_second.errors.values, atol=1e-9)
    np.testing.assert_allclose(e.uncertainties, off_second.errors.uncertainties, atol=1e-12)
    assert stamp_to_s(e.header.stamp) == pytest.approx(off_second.stamp_s)
    assert stamp_to_s(ref.result.errors.header.stamp) == pytest.approx(off_ref.stamp_s)
    assert second.result.duration_s == pytest.approx(95.0)

    # physics: the change the probe saw is the twin's true change between the cycles
    n = len(offline.truth) // 2
    true_change = {c: np.mean([t[c] for t in offline.truth[n:]])
                   - np.mean([t[c] for t in offline.truth[:n]]) for c in SPHERE_COMPONENTS}
    assert true_change["E_Z0T"] > 3.0          # the machine did warm up in between
    for c, v, u in zip(e.component_names, e.values, e.uncertainties):
        assert abs(v - true_change[c]) <= 4.0 * u, (c, v, true_change[c], u)
