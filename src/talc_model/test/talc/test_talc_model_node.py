"""The talc_model node in simulated lock-step time with a fake ProbeCycle server (2nd process)."""
from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.ros]
HERE = pathlib.Path(__file__).resolve().parent
STEP = 300.0

MODEL_YAML = """
component_names: [E_X0C]
input_names: [a, b]
model_step_s: 300.0
cp_interval_s: 205.0        # + 95 s cycle = one probe per step in the calibration phase
post_cp_interval_h: 0.5
ng_interval_min: 3.4166666666666665
ng_measurements: 2
update_interval_h: 100.0
na_max: 1
nb_max: 1
nb_max_final: 1
cp_gap_fill: predict        # the fake plant jumps between samples: no interpolation of failed CP probes
hold_fallback: false        # the fake machine measures against the published prediction; checked exactly below
"""


def spawn(args, log_path):
    f = open(log_path, "w")
    return subprocess.Popen(args, env=dict(os.environ), stdout=f, stderr=subprocess.STDOUT, text=True), f


def stop(proc, f):
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    f.close()


def spin_until(executor, condition, deadline_s, procs=()):
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if condition():
            return True
        if any(p.poll() is not None for p in procs):
            return condition()
        executor.spin_once(timeout_sec=0.02)
    return condition()


def test_probe_scheduling_in_lockstep_with_failures(tmp_path, ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, LATCHED_QOS, SENSOR_QOS, TOPIC_ERRORS_MEASURED,
                                           TOPIC_ERRORS_PREDICTED, TOPIC_MODEL_STATUS, TOPIC_TEMPERATURES,
                                           stamp_to_s)
    from thermal_comp_msgs.msg import ModelStatus, TemperatureArray, ThermalErrors
    from talc_model.model_persistence import load_model

    sys.path.insert(0, str(HERE))
    from fake_machine import scenario, true_error

    n_steps = 36
    cfg = tmp_path / "talc.yaml"
    cfg.write_text(MODEL_YAML)
    state = tmp_path / "state" / "talc.json"
    log = tmp_path / "machine.jsonl"
    test_node = Node("talc_test_observer", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(test_node)
    statuses, predicted, measured, temps_seen = [], [], [], []
    test_node.create_subscription(ModelStatus, TOPIC_MODEL_STATUS, statuses.append, LATCHED_QOS)
    test_node.create_subscription(ThermalErrors, TOPIC_ERRORS_PREDICTED, predicted.append, EVENT_QOS)
    test_node.create_subscription(ThermalErrors, TOPIC_ERRORS_MEASURED, measured.append, EVENT_QOS)
    test_node.create_subscription(TemperatureArray, TOPIC_TEMPERATURES, temps_seen.append, SENSOR_QOS)
    node, f2 = spawn([sys.executable, "-m", "talc_model.talc_model_node", "--ros-args",
                      "-p", f"model_config:={cfg}", "-p", f"state_path:={state}",
                      "-p", "lockstep_participant:=true", "-p", "probe_result_wait_s:=6.0",
                      "-p", "action_server_wait_s:=20.0"], tmp_path / "node.log")
    # the observer sees the node's outputs before the machine starts the clock
    topics = (TOPIC_MODEL_STATUS, TOPIC_ERRORS_PREDICTED, TOPIC_ERRORS_MEASURED)
    assert spin_until(ex, lambda: all(test_node.count_publishers(tp) >= 1 for tp in topics), 30.0, (node,))
    machine, f1 = spawn([sys.executable, str(HERE / "fake_machine.py"), str(log), "--steps", str(n_steps),
                         "--fail", "3", "--hang", "6"], tmp_path / "machine.log")

    def finished():
        return log.is_file() and '"done"' in log.read_text()
    try:
        assert spin_until(ex, finished, 90.0, (machine, node)), "the lock-step scenario did not finish"
        last_t = (n_steps - 1) * STEP
        assert spin_until(ex, lambda: statuses and stamp_to_s(statuses[-1].header.stamp) >= last_t
                          and len(temps_seen) == n_steps, 10.0)
    finally:
        ex.remove_node(test_node)
        test_node.destroy_node()
        stop(node, f2)
        stop(machine, f1)
    node_log = (tmp_path / "node.log").read_text()
    # in the order the goals came (a line is written when a goal ends: the given-up goal 6 may
    # end after goal 7, since the node acks once it gives up and the cancel request may come later)
    goals = sorted((json.loads(line) for line in log.read_text().splitlines() if '"goal"' in line),
                   key=lambda g: g["goal"])
    # the clock stood still while a cycle ran: the ack for t_k was withheld until its result
    # (a timed-out cycle is given up: the node cancels it and acks, so the machine may move on
    # before the cancel request reaches the server)
    assert all(g["prediction_for_t"] for g in goals), goals
    assert all(g["t_end"] == g["t_start"] for g in goals if g["outcome"] != "cancelled"), goals
    starts = [g["t_start"] for g in goals]
    assert starts[0] == 0.0 and goals[0]["set_reference"]
    assert not any(g["set_reference"] for g in goals[1:])
    assert [g["outcome"] for g in goals[:7]] == ["ok", "ok", "aborted", "ok", "ok", "cancelled", "ok"]
    st = statuses[-1]
    assert st.phase == ModelStatus.PHASE_COMPENSATION, st.message
    assert st.failed_probing_cycles == 2
    assert st.probing_cycles == sum(g["outcome"] == "ok" for g in goals) == len(measured), (len(predicted), len(statuses), len(measured))
    assert "failed (not learned from)" in node_log
    # calibration phase: one probe per step, failed cycles retried at the next step
    first_comp = min(stamp_to_s(s.header.stamp) for s in statuses if s.phase != ModelStatus.PHASE_CALIBRATION)
    cp_starts = [s for s in starts if s <= first_comp]     # the last CP probe ends the CP
    assert cp_starts == [k * STEP for k in range(len(cp_starts))]
    # compensation phase: sparse probing every 0.5 h + 95 s cycle -> every 7th step
    post = [s for s in starts if s > first_comp]
    assert post and np.all(np.diff([max(cp_starts)] + post) == 7 * STEP)
    # the exact static plant is learned: predictions equal the true error, residuals vanish
    temps = scenario(n_steps)
    for msg in predicted:
        k = int(round(stamp_to_s(msg.header.stamp) / STEP))
        if k * STEP > first_comp:
            assert msg.component_names == ["E_X0C"] and list(msg.units) == [ThermalErrors.UNIT_UM]
            assert abs(msg.values[0] - true_error(temps[k])) < 1e-6
    ok_post = [g for g in goals if g["outcome"] == "ok" and g["t_start"] > first_comp]
    assert ok_post and all(abs(g["measured"]) < 1e-6 for g in ok_post)
    # sensor c was excluded (held) while its status was FAILED
    excl = {int(round(stamp_to_s(s.header.stamp) / STEP)): list(s.excluded_sensor_ids) for s in statuses}
    assert excl[12] == ["c"] and excl[n_steps - 1] == []
    # persisted: a restart resumes the same model in the compensation phase
    resumed = load_model(state)
    assert resumed.phase == "compensation" and resumed.failed_probing_cycles == 2
