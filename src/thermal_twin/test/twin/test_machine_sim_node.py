"""machine_sim across two processes in simulated time: lock-step with a test participant,
the touch-probe service, applied offsets; the stream equals the offline core exactly."""
from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.ros]

HOURS = 0.25            # 16 instants of 60 s
PROBE_AT_K = 5          # the participant probes before acknowledging this instant
OFFSET_Z_UM = 7.0


def _offline_reference():
    """What machine_sim must publish: the pure core driven through the same sequence."""
    from thermal_twin.machine.artefact_geometry import nominal_sphere_centre, touch_trigger_position, DEFAULT_GEOMETRY
    from thermal_twin.machine.schema import load_machine
    from thermal_twin.sim.scenario_runner import ScenarioRunner
    from thermal_twin.sim.scenarios import make_timeline
    m = load_machine("nmv5000")
    r = ScenarioRunner(m, make_timeline("nmv5000", "talc-178h-dry", hours=HOURS, seed=3), seed=3)
    out = []
    probe = None
    while True:
        out.append((r.t_s, r.sensor_readings(), r.errors()))
        if len(out) - 1 == PROBE_AT_K:
            r.idle(95.0)
            start, direction = _probe_move(nominal_sphere_centre, DEFAULT_GEOMETRY)
            probe = (r.t_s, touch_trigger_position(0, 0.0, 0.0, start, direction, 20.0, r.errors(),
                                                   {"Z": OFFSET_Z_UM}, rng=None))
            r.resume()
        if r.done:
            break
        r.step()
    return out, probe


def _probe_move(nominal_sphere_centre, geometry):
    c = nominal_sphere_centre(0.0)
    return c + np.array([0.0, 0.0, geometry.contact_radius_mm + 5.0]), np.array([0.0, 0.0, -1.0])


def test_machine_sim_lockstep_probe_and_offsets():
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, SENSOR_QOS, SERVICE_TOUCH_PROBE, TOPIC_ERRORS_TRUE,
                                           TOPIC_OFFSETS, TOPIC_SIM_SYNC, TOPIC_TWIN_SENSORS, s_to_stamp,
                                           stamp_to_s)
    from thermal_comp_msgs.msg import AxisOffsets, SimSync, TemperatureArray, ThermalErrors
    from thermal_comp_msgs.srv import TouchProbe
    from thermal_twin.machine.artefact_geometry import DEFAULT_GEOMETRY, nominal_sphere_centre

    expected, expected_probe = _offline_reference()
    proc = subprocess.Popen(
        [sys.executable, "-m", "thermal_twin.machine_sim_node", "--ros-args",
         "-p", "machine:=nmv5000", "-p", "scenario:=talc-178h-dry", "-p", f"hours:={HOURS}", "-p", "seed:=3",
         "-p", "lockstep_participants:=['twin_test_participant']", "-p", "probe_noise:=false",
         "-p", "probe_offsets_wait_s:=0.2",   # its offsets stay stamped 0 (a bridge that answered once)
         "-p", "shutdown_when_done:=true"],
        env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("twin_test_participant", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    readings, truth, clocks = {}, {}, []
    node.create_subscription(TemperatureArray, TOPIC_TWIN_SENSORS,
                             lambda m: readings.setdefault(stamp_to_s(m.header.stamp), m), SENSOR_QOS)
    node.create_subscription(ThermalErrors, TOPIC_ERRORS_TRUE,
                             lambda m: truth.setdefault(stamp_to_s(m.header.stamp), m), EVENT_QOS)
    node.create_subscription(Clock, "/clock", lambda m: clocks.append(stamp_to_s(m.clock)), SENSOR_QOS)
    sync = node.create_publisher(SimSync, TOPIC_SIM_SYNC, EVENT_QOS)
    offsets = node.create_publisher(AxisOffsets, TOPIC_OFFSETS, EVENT_QOS)
    probe = node.create_client(TouchProbe, SERVICE_TOUCH_PROBE)

    def spin_until(cond, timeout_s, what):
        deadline = time.monotonic() + timeout_s
        while not cond():
            if time.monotonic() > deadline or proc.poll() not in (None, 0):
                raise AssertionError(f"timed out waiting for {what}; machine_sim said:\n"
                                     f"{proc.stdout.read() if proc.poll() is not None else ''}")
            ex.spin_once(timeout_sec=0.05)

    try:
        acked = 0
        probe_result = None
        while acked < len(expected):
            t_k = expected[acked][0]
            spin_until(lambda: t_k in readings and t_k in truth, 30.0, f"instant t={t_k}")
            if acked == 0:
                # the CNC bridge holds a Z offset: the probe must see true error minus it
                spin_until(lambda: offsets.get_subscription_count() > 0, 10.0, "offsets subscriber")
                offsets.publish(AxisOffsets(axis_names=["X", "Y", "Z"], commanded_offsets_um=[0.0, 0.0, OFFSET_Z_UM],
                                            applied_offsets_um=[0.0, 0.0, OFFSET_Z_UM], applied=[True] * 3,
                                            limits_hit=[0] * 3, compensation_enabled=True))
            if acked == PROBE_AT_K:
                assert probe.wait_for_service(timeout_sec=10.0)
                start, direction = _probe_move(nominal_sphere_centre, DEFAULT_GEOMETRY)
                fut = probe.call_async(TouchProbe.Request(artefact=0, c_axis_deg=0.0, b_axis_deg=0.0,
                                                          start_mm=start.tolist(), direction=direction.tolist(),
                                                          max_travel_mm=20.0, duration_s=95.0))
                spin_until(fut.done, 10.0, "touch probe answer")
                probe_result = fut.result()
                # a malformed move is refused and costs no simulated time (the stream below
                # still equals the reference, which has no such pause)
                bad = probe.call_async(TouchProbe.Request(artefact=0, start_mm=start.tolist(), direction=[0.0, 0.0, -2.0],
                                                          max_travel_mm=20.0, duration_s=95.0))
                spin_until(bad.done, 10.0, "answer to a bad touch request")
                bad_result = bad.result()
            sync.publish(SimSync(node_name="twin_test_participant", processed_until=s_to_stamp(t_k)))
            acked += 1
        proc.wait(timeout=20)
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=10)
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)

    # the stream in simulated time equals the offline core, instant by instant
    assert sorted(readings) == [e[0] for e in expected]
    for t_k, sensors, errors in expected:
        msg = readings[t_k]
        assert list(msg.sensor_ids) == list(sensors)
        np.testing.assert_array_equal(np.array(msg.temperatures_degc), np.array(list(sensors.values())))
        np.testing.assert_allclose(np.array(truth[t_k].values), np.array(list(errors.values())), atol=1e-9)
        assert list(truth[t_k].component_names) == list(errors)
    # probing cost simulated time: instants after the probe are shifted by its 95 s
    assert expected[PROBE_AT_K + 1][0] - expected[PROBE_AT_K][0] == pytest.approx(60.0 + 95.0)
    # the touch probe: true geometry minus the applied Z offset, stamped after 95 s
    t_probe, (trig, pos) = expected_probe
    assert probe_result.triggered and trig
    assert stamp_to_s(probe_result.stamp) == pytest.approx(t_probe)
    np.testing.assert_allclose(probe_result.trigger_position_mm, pos, atol=1e-9)
    assert math.isclose(t_probe, expected[PROBE_AT_K][0] + 95.0)
    assert clocks == sorted(clocks)                 # /clock never runs backwards
    assert not bad_result.triggered and "direction" in bad_result.message and "nothing moved" in bad_result.message
    assert stamp_to_s(bad_result.stamp) == pytest.approx(t_probe)
