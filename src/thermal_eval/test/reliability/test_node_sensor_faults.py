"""Sensor faults at the ROS nodes: the talc_model node lists every non-OK sensor in
ModelStatus.excluded_sensor_ids and ignores late (older) temperatures; temperature_publisher
turns late / out-of-order twin readings into strictly increasing temperatures."""
from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import pytest

from thermal_eval.reliability import fault_injection as fi
pytestmark = [pytest.mark.slow, pytest.mark.ros]
NS = "/reliability_nodes"


def _spawn(module, params, log_path):
    args = [sys.executable, "-m", module, "--ros-args", "-r", f"__ns:={NS}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={v}"]
    f = open(log_path, "w")
    return subprocess.Popen(args, env=dict(os.environ), stdout=f, stderr=subprocess.STDOUT, text=True), f


def _stop(proc, f):
    if proc.poll() is None:
        proc.send_signal(2)
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    f.close()


def _spin_until(ex, cond, deadline_s, proc, what):
    end = time.monotonic() + deadline_s
    while not cond():
        if time.monotonic() > end or proc.poll() is not None:
            raise AssertionError(f"{what} (process exit {proc.poll()})")
        ex.spin_once(timeout_sec=0.02)


def test_model_excludes_flagged_sensors_and_ignores_late_temperatures(tmp_path, ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import Header

    from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, LATCHED_QOS, SENSOR_QOS, TOPIC_ERRORS_PREDICTED,
                                           TOPIC_MODEL_STATUS, TOPIC_TEMPERATURES, s_to_stamp, stamp_to_s)
    from thermal_comp_msgs.msg import ModelStatus, TemperatureArray, ThermalErrors

    proc, f = _spawn("talc_model.talc_model_node", {"action_server_wait_s": 0.0}, tmp_path / "model.log")
    node = Node("fault_observer", namespace=NS, context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    statuses, preds = [], []
    subs = [node.create_subscription(ModelStatus, TOPIC_MODEL_STATUS, statuses.append, LATCHED_QOS),
            node.create_subscription(ThermalErrors, TOPIC_ERRORS_PREDICTED,
                                     lambda m: preds.append(stamp_to_s(m.header.stamp)), EVENT_QOS)]
    pub = node.create_publisher(TemperatureArray, TOPIC_TEMPERATURES, SENSOR_QOS)
    ids = ["ambient", "ws_mwf", "c_coolant_delta", "c_motor_internal"]
    ok, stale, oor, failed = (TemperatureArray.STATUS_OK, TemperatureArray.STATUS_STALE,
                              TemperatureArray.STATUS_OUT_OF_RANGE, TemperatureArray.STATUS_FAILED)
    frames = [(0.0, [20.0, 21.0, 0.5, 30.0], [ok] * 4),
              (300.0, [20.1, math.nan, 0.5, 30.0], [ok, failed, ok, ok]),
              (600.0, [20.2, 95.0, 0.5, 30.0], [ok, oor, stale, ok]),
              (900.0, [20.3, 21.2, 0.6, 30.0], [ok] * 4)]
    try:
        # matched on both of our ends (the graph alone says nothing about the node's writers)
        _spin_until(ex, lambda: pub.get_subscription_count() >= 1
                    and all(s.get_publisher_count() >= 1 for s in subs), 60.0, proc, "talc_model node not discovered")
        # Discovery is not symmetric: the node's prediction writer may not know our reader yet, and
        # a volatile prediction sent before it does is lost. The first instant is re-sent until its
        # prediction is heard; the node answers a repeated instant with the same prediction, never
        # a second update.
        t0, vals0, st0 = frames[0]
        for _ in range(30):
            pub.publish(TemperatureArray(header=Header(stamp=s_to_stamp(t0)), sensor_ids=ids,
                                         temperatures_degc=vals0, status=st0))
            try:
                _spin_until(ex, lambda: t0 in preds, 2.0, proc, "warm-up")
                break
            except AssertionError:
                if proc.poll() is not None:
                    raise
        else:
            raise AssertionError(f"no prediction for the first instant (process exit {proc.poll()})")
        seen = {}
        for t, vals, st in frames:
            pub.publish(TemperatureArray(header=Header(stamp=s_to_stamp(t)), sensor_ids=ids,
                                         temperatures_degc=vals, status=st))
            _spin_until(ex, lambda: t in preds, 30.0, proc, f"no prediction for t={t}")
            _spin_until(ex, lambda: statuses and stamp_to_s(statuses[-1].header.stamp) >= t, 30.0, proc,
                        f"no model status for t={t}")
            seen[t] = sorted(statuses[-1].excluded_sensor_ids)
        # a late message (older than the last instant) is ignored: no prediction for it
        pub.publish(TemperatureArray(header=Header(stamp=s_to_stamp(450.0)), sensor_ids=ids,
                                     temperatures_degc=[20.0] * 4, status=[ok] * 4))
        pub.publish(TemperatureArray(header=Header(stamp=s_to_stamp(1200.0)), sensor_ids=ids,
                                     temperatures_degc=[20.4, 21.3, 0.6, 30.0], status=[ok] * 4))
        _spin_until(ex, lambda: 1200.0 in preds, 30.0, proc, "no prediction for t=1200")
    finally:
        _stop(proc, f)
        ex.shutdown()
        node.destroy_node()
    assert seen[0.0] == [] and seen[900.0] == []
    assert seen[300.0] == ["ws_mwf"]
    assert seen[600.0] == ["c_coolant_delta", "ws_mwf"]
    assert 450.0 not in preds and preds == sorted(preds)


def test_temperature_publisher_turns_out_of_order_readings_into_increasing_instants(tmp_path, ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import Header

    from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, TOPIC_TEMPERATURES, TOPIC_TWIN_SENSORS, s_to_stamp, stamp_to_s
    from thermal_comp_msgs.msg import SimSync, TemperatureArray
    from thermal_sensors.temperature_publisher_node import SIM_SYNC_QOS

    proc, f = _spawn("thermal_sensors.temperature_publisher_node",
                     {"source": "twin", "sensor_config": "nmv5000", "lockstep_participant": True},
                     tmp_path / "sensors.log")
    node = Node("fault_feeder", namespace=NS, context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    temps, acks = [], []
    node.create_subscription(TemperatureArray, TOPIC_TEMPERATURES,
                             lambda m: temps.append(stamp_to_s(m.header.stamp)), SENSOR_QOS)
    node.create_subscription(SimSync, "sim_sync", lambda m: acks.append(stamp_to_s(m.processed_until)),
                             SIM_SYNC_QOS)
    twin = node.create_publisher(TemperatureArray, TOPIC_TWIN_SENSORS, SENSOR_QOS)
    ids = ["ambient", "ws_mwf", "c_coolant_delta", "c_motor_internal"]
    times = [300.0 * (k + 1) for k in range(8)]
    order = fi.reorder_late(len(times), {1: 2, 4: 2})        # instants 1 and 4 arrive two late

    def frame(t, i):
        return TemperatureArray(header=Header(stamp=s_to_stamp(t)), sensor_ids=ids,
                                temperatures_degc=[20.0 + 0.01 * i, 21.0, 0.5, 30.0], status=[0] * 4)
    try:
        _spin_until(ex, lambda: twin.get_subscription_count() >= 1 and node.count_publishers(TOPIC_TEMPERATURES) >= 1
                    and node.count_publishers("sim_sync") >= 1, 60.0, proc, "temperature_publisher not discovered")
        # Discovery is not symmetric: the node's writers may not know our readers yet, and a
        # volatile ack sent before they do is lost. A warm-up instant (t=0) is re-sent until its
        # ack and its temperatures are heard; the node re-publishes a repeated instant unchanged.
        for _ in range(30):
            twin.publish(frame(0.0, -1))
            try:
                _spin_until(ex, lambda: 0.0 in acks and 0.0 in temps, 2.0, proc, "warm-up")
                break
            except AssertionError:
                if proc.poll() is not None:
                    raise
        else:
            raise AssertionError(f"no ack and temperatures for the warm-up instant (process exit {proc.poll()})")
        for i in order:
            twin.publish(frame(times[i], i))
            _spin_until(ex, lambda: times[i] in acks, 30.0, proc, f"no ack for t={times[i]}")
    finally:
        _stop(proc, f)
        ex.shutdown()
        node.destroy_node()
    temps = [t for t in temps if t > 0.0]
    acks = [t for t in acks if t > 0.0]
    late = {times[1], times[4]}
    assert temps == sorted(temps) and len(set(temps)) == len(temps)   # never backwards, never twice
    assert not late & set(temps)                     # a late instant is acknowledged, not published
    assert sorted(set(acks)) == times                # every instant acknowledged (lock-step goes on)
