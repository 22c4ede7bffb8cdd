"""The temperature_publisher node across processes, in simulated time (lock-step)."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from thermal_sensors.replay_source import ReplaySource
from thermal_sensors.sensor_config import load_sensor_config
from thermal_sensors.temperature_frame import TemperatureFrameBuilder

from sensor_test_data import make_recording, sensors_yaml, ports  # noqa: F401 (fixture)

pytestmark = [pytest.mark.slow, pytest.mark.ros]
MODULE = "thermal_sensors.temperature_publisher_node"


def spawn_node(params: dict, name: str, env: dict | None = None):
    args = [sys.executable, "-m", MODULE, "--ros-args", "-r", f"__node:={name}"]
    for k, v in params.items():
        v = str(v).lower() if isinstance(v, bool) else v
        args += ["-p", f"{k}:={v}"]
    return subprocess.Popen(args, env={**os.environ, **(env or {})}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def stop_node(proc) -> str:
    if proc.poll() is None:
        proc.terminate()
    try:
        out, _ = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out


def spin_until(executor, condition, deadline_s: float, proc=None) -> bool:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if condition():
            return True
        if proc is not None and proc.poll() is not None:
            return condition()
        executor.spin_once(timeout_sec=0.05)
    return condition()


def expected_frames(csv, config, times):
    src = ReplaySource.from_csv(csv, config)
    b = TemperatureFrameBuilder(config)
    return [b.build(src.sample(float(t))) for t in times]


def check_messages(msgs, frames):
    assert len(msgs) == len(frames)
    for m, f in zip(msgs, frames):
        assert m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 == pytest.approx(f.t_s, abs=1e-9)
        assert tuple(m.sensor_ids) == f.sensor_ids
        assert list(m.status) == [int(s) for s in f.status]
        np.testing.assert_allclose(np.array(m.temperatures_degc), f.temperatures_degc,
                                   atol=1e-9, rtol=0, equal_nan=True)


@pytest.fixture
def setup(tmp_path, ports):
    csv = tmp_path / "rec.csv"
    t, cols = make_recording(csv, n_rows=20, dt_s=10.0)
    cfg = tmp_path / "sensors.yaml"
    cfg.write_text(sensors_yaml(ports))
    return csv, cfg, t, cols


@pytest.mark.parametrize("executor", ["single", "events"])
def test_twin_source_in_lockstep_with_a_simulated_machine(setup, ros_context, executor):
    """The test plays machine_sim: it publishes /clock and twin/sensor_readings for t_k and
    advances only after the node's SimSync for t_k, which must follow temperatures(t_k);
    with either executor of the node runtime (THERMAL_COMP_EXECUTOR, the demo uses events)."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, s_to_stamp, stamp_to_s
    from thermal_comp_msgs.msg import SimSync, TemperatureArray
    from thermal_sensors.temperature_publisher_node import CLOCK_QOS, SIM_SYNC_QOS

    csv, cfg, t, cols = setup
    config = load_sensor_config(cfg)
    proc = spawn_node({"source": "twin", "sensor_config": str(cfg), "lockstep_participant": True,
                       "use_sim_time": True}, "sensors", env={"THERMAL_COMP_EXECUTOR": executor})
    node = Node("fake_machine_sim", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    events: list[tuple[str, float]] = []
    temps: list = []
    subs = [node.create_subscription(TemperatureArray, "temperatures",
                                     lambda m: (temps.append(m), events.append(("T", stamp_to_s(m.header.stamp)))),
                                     SENSOR_QOS),
            node.create_subscription(SimSync, "sim_sync",
                                     lambda m: events.append(("S", stamp_to_s(m.processed_until)))
                                     if m.node_name == "sensors" else None, SIM_SYNC_QOS)]
    clock_pub = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    twin_pub = node.create_publisher(TemperatureArray, "twin/sensor_readings", SENSOR_QOS)
    twin_ids = ["ambient", "spindle", "stuck", "hot", "cold"]
    try:
        # matched on our own ends, not only present in the graph
        assert spin_until(ex, lambda: twin_pub.get_subscription_count() >= 1 and clock_pub.get_subscription_count() >= 1
                          and all(s.get_publisher_count() >= 1 for s in subs), 30.0, proc), stop_node(proc)
        for k, tk in enumerate(t):
            clock_pub.publish(Clock(clock=s_to_stamp(tk)))
            twin_pub.publish(TemperatureArray(
                header=Header(stamp=s_to_stamp(tk)), sensor_ids=twin_ids,
                temperatures_degc=[float(cols[f"{s}_c"][k]) for s in twin_ids], status=[0] * 5))
            assert spin_until(ex, lambda: ("S", tk) in events, 20.0, proc), (k, stop_node(proc))
        # machine_sim re-sends an instant whose acknowledgement it missed (a consumer may have
        # restarted): the same frame again, then the ack
        twin_pub.publish(TemperatureArray(
            header=Header(stamp=s_to_stamp(t[-1])), sensor_ids=twin_ids,
            temperatures_degc=[float(cols[f"{s}_c"][-1]) for s in twin_ids], status=[0] * 5))
        assert spin_until(ex, lambda: events.count(("S", t[-1])) == 2, 20.0, proc)
    finally:
        out = stop_node(proc)
        ex.shutdown()
        node.destroy_node()
    # temperatures(t_k) strictly before SimSync(t_k), in order; the re-sent instant re-published
    assert events == [e for tk in t for e in (("T", tk), ("S", tk))] + [("T", t[-1]), ("S", t[-1])], out
    from rclpy.serialization import serialize_message
    assert serialize_message(temps[-1]) == serialize_message(temps[-2])   # NaN-safe equality
    temps = temps[:-1]
    check_messages(temps, expected_frames(csv, config, t))


def test_replay_as_time_master_waits_for_its_lockstep_participant(setup, ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, stamp_to_s
    from thermal_comp_msgs.msg import SimSync, TemperatureArray
    from thermal_sensors.temperature_publisher_node import CLOCK_QOS, SIM_SYNC_QOS

    csv, cfg, t, cols = setup
    config = load_sensor_config(cfg)
    proc = spawn_node({"source": "replay", "sensor_config": str(cfg), "csv_path": str(csv),
                       "time_master": True, "lockstep_participants": "['model']"}, "replayer")
    node = Node("model", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    sync_pub = node.create_publisher(SimSync, "sim_sync", SIM_SYNC_QOS)
    clock: list[float] = []
    temps: list = []
    hold = {"ack": True}

    def on_temps(m):
        temps.append(m)
        if hold["ack"]:
            sync_pub.publish(SimSync(header=Header(stamp=m.header.stamp), node_name="model",
                                     processed_until=m.header.stamp))
    node.create_subscription(TemperatureArray, "temperatures", on_temps, SENSOR_QOS)
    node.create_subscription(Clock, "/clock", lambda m: clock.append(stamp_to_s(m.clock)), CLOCK_QOS)
    try:
        assert spin_until(ex, lambda: len(temps) >= 5, 30.0, proc), stop_node(proc)
        hold["ack"] = False           # the participant stops acknowledging: time must stop
        n = len(temps)
        spin_until(ex, lambda: len(temps) > n + 1, 1.5)
        assert len(temps) <= n + 1    # at most the step already in flight
        last = temps[-1].header.stamp
        sync_pub.publish(SimSync(header=Header(stamp=last), node_name="model", processed_until=last))
        hold["ack"] = True
        assert spin_until(ex, lambda: len(temps) == len(t), 30.0, proc), stop_node(proc)
        spin_until(ex, lambda: len(clock) == len(t), 5.0)
    finally:
        out = stop_node(proc)
        ex.shutdown()
        node.destroy_node()
    assert clock == pytest.approx(list(t)), out
    check_messages(temps, expected_frames(csv, config, t))


def test_modbus_source_node_flags_a_silent_module_and_keeps_publishing(setup, ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from thermal_comp_common.runtime.node_runtime import SENSOR_QOS
    from thermal_comp_msgs.msg import TemperatureArray
    from thermal_sensors.rtd_emulator import RtdEmulator

    csv, cfg, t, cols = setup
    config = load_sensor_config(cfg)
    emu = RtdEmulator(config)
    emu.start()
    emu.set_temperatures({"ambient": 21.4, "spindle": 30.2, "stuck": 24.3, "hot": 55.5, "cold": -12.5})
    proc = spawn_node({"source": "modbus", "sensor_config": str(cfg), "period_s": 0.1}, "rtd")
    node = Node("observer", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    temps: list = []
    node.create_subscription(TemperatureArray, "temperatures", temps.append, SENSOR_QOS)
    try:
        assert spin_until(ex, lambda: temps and list(temps[-1].status) == [0] * 5, 30.0, proc), stop_node(proc)
        assert temps[-1].temperatures_degc[4] == pytest.approx(-12.5)
        emu.set_silent("rtd_c")
        assert spin_until(ex, lambda: list(temps[-1].status) == [0, 0, 0, 0, 3], 10.0, proc)
        n = len(temps)
        # the executor is not blocked by the timeouts: messages keep coming every 0.1 s
        assert spin_until(ex, lambda: len(temps) >= n + 5, 10.0, proc)
        emu.set_silent("rtd_c", False)
        assert spin_until(ex, lambda: list(temps[-1].status) == [0] * 5, 10.0, proc)
    finally:
        out = stop_node(proc)
        ex.shutdown()
        node.destroy_node()
        emu.stop()
    assert "sensor cold: failed" in out and "sensor cold: ok again" in out


def test_bad_sensor_config_stops_the_node_with_one_line_naming_the_key(tmp_path):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("sensors:\n  - {id: a, range_degc: [30, 10]}\n")
    proc = spawn_node({"source": "twin", "sensor_config": str(cfg)}, "sensors")
    out = proc.communicate(timeout=60)[0]
    assert proc.returncode == 2, out
    assert "sensors[0].range_degc: [30, 10]" in out
    proc = spawn_node({"source": "modbus", "sensor_config": str(cfg).replace("bad", "none")}, "sensors")
    out = proc.communicate(timeout=60)[0]
    assert proc.returncode == 2 and "no such sensor config file" in out, out


def test_with_the_real_machine_sim_in_lockstep(ros_context):
    """machine_sim (nmv5000, 30 min at its default step) waits for this node on every instant;
    every twin reading comes out once, stamped alike, uncalibrated values unchanged."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from thermal_comp_common.runtime.node_runtime import SENSOR_QOS
    from thermal_comp_msgs.msg import TemperatureArray

    node = Node("observer", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    twin, temps = {}, {}
    # the observer takes part in the lock-step too, so machine_sim cannot run ahead of its
    # discovery on a loaded machine (it re-sends an instant until every participant acked it)
    from thermal_comp_common.runtime.node_runtime import EVENT_QOS
    from thermal_comp_msgs.msg import SimSync
    sync = node.create_publisher(SimSync, "sim_sync", EVENT_QOS)

    def on_twin(m):
        twin.setdefault((m.header.stamp.sec, m.header.stamp.nanosec), m)
        sync.publish(SimSync(header=m.header, node_name="observer", processed_until=m.header.stamp))

    node.create_subscription(TemperatureArray, "twin/sensor_readings", on_twin, SENSOR_QOS)
    node.create_subscription(TemperatureArray, "temperatures",
                             lambda m: temps.setdefault((m.header.stamp.sec, m.header.stamp.nanosec), []).append(m),
                             SENSOR_QOS)
    pub = spawn_node({"source": "twin", "sensor_config": "nmv5000", "lockstep_participant": True,
                      "use_sim_time": True}, "sensors")
    # the observer must be matched before time starts, or it would miss the first instants
    spin_until(ex, lambda: node.count_publishers("temperatures") >= 1, 30.0, pub)
    sim = subprocess.Popen([sys.executable, "-m", "thermal_twin.machine_sim_node", "--ros-args",
                            "-p", "machine:=nmv5000", "-p", "scenario:=talc-178h-dry", "-p", "hours:=0.5",
                            "-p", "lockstep_participants:=['sensors','observer']", "-p", "shutdown_when_done:=true"],
                           env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        spin_until(ex, lambda: sim.poll() is not None, 90.0)
        spin_until(ex, lambda: len(temps) >= len(twin) > 0, 5.0)
    finally:
        sim_out = stop_node(sim)
        out = stop_node(pub)
        ex.shutdown()
        node.destroy_node()
    assert sim.returncode == 0, sim_out
    assert len(twin) > 10 and sorted(temps) == sorted(twin), (len(twin), len(temps), out)
    for key, msgs in temps.items():
        # an instant comes again only when machine_sim re-sent it (a late ack), and unchanged
        from rclpy.serialization import serialize_message
        assert all(serialize_message(x) == serialize_message(msgs[0]) for x in msgs)
        m, raw = msgs[0], twin[key]
        assert list(m.sensor_ids) == ["ambient", "ws_mwf", "c_coolant_delta", "c_motor_internal"]
        by_id = dict(zip(raw.sensor_ids, raw.temperatures_degc))
        np.testing.assert_array_equal(m.temperatures_degc, [by_id[s] for s in m.sensor_ids])
        assert list(m.status) == [0, 0, 0, 0]       # healthy, in range, 30 min < stale_after_s
