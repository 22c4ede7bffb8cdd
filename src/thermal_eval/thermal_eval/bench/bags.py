"""Benchmark ``bags``: record and replay throughput, in messages and simulated hours per second.

A synthetic twin-like cell stream (fixed seed) is written, read, recorded over DDS and
replayed; what each stage measures is in docs/bags.md ("Benchmark").
"""
from __future__ import annotations

import pathlib
import shutil
import tempfile
import threading
import time

import numpy as np
from thermal_comp_common.bags import msg_definitions as md
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.writer import BagWriter, TopicInfo
from thermal_comp_common.components import FIVE_AXIS_COMPONENTS

STEP_S = 60.0
N_SENSORS = 16
COMPONENTS = list(FIVE_AXIS_COMPONENTS)


def synthetic_stream(instants: int, seed: int = 0) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, time ns, CDR bytes) of ``instants`` twin-like instants."""
    store = md.typestore()
    T, H = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    Temps = store.types["thermal_comp_msgs/msg/TemperatureArray"]
    Errs = store.types["thermal_comp_msgs/msg/ThermalErrors"]
    State = store.types["thermal_comp_msgs/msg/MachineState"]
    rng = np.random.default_rng(seed)
    temps = 20 + np.cumsum(rng.normal(0, 0.02, (instants, N_SENSORS)), axis=0)
    errs = np.cumsum(rng.normal(0, 0.1, (instants, len(COMPONENTS))), axis=0)
    ids = [f"t{i + 1}" for i in range(N_SENSORS)]
    out = []
    for k in range(instants):
        t_ns = int(k * STEP_S * 1e9)
        h = H(stamp=T(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="")
        out.append(("/machine_state", "thermal_comp_msgs/msg/MachineState", t_ns, bytes(store.serialize_cdr(
            State(header=h, spindle_names=[], spindle_speeds_rpm=np.zeros(0), rotary_axis_names=["C"],
                  rotary_axis_speeds_rpm=np.array([600.0 * (k // 60 % 2)]), axis_names=[],
                  axis_positions=np.zeros(0), coolant_on=False, coolant_temperature_degc=21.0,
                  door_open=False, drive_names=[], drive_powers_w=np.zeros(0), machine_busy_probing=False),
            "thermal_comp_msgs/msg/MachineState"))))
        out.append(("/temperatures", "thermal_comp_msgs/msg/TemperatureArray", t_ns, bytes(store.serialize_cdr(
            Temps(header=h, sensor_ids=ids, temperatures_degc=temps[k],
                  status=np.zeros(N_SENSORS, np.uint8)), "thermal_comp_msgs/msg/TemperatureArray"))))
        out.append(("/errors/ground_truth", "thermal_comp_msgs/msg/ThermalErrors", t_ns, bytes(store.serialize_cdr(
            Errs(header=h, source=2, model_kind="twin", component_names=COMPONENTS, values=errs[k],
                 units=np.array([0, 0, 0, 0, 1, 1, 1], np.uint8), uncertainties=np.full(7, np.nan)),
            "thermal_comp_msgs/msg/ThermalErrors"))))
    return out


def _rates(n_msgs: int, instants: int, wall: float) -> dict:
    return {"messages": n_msgs, "wall_s": round(wall, 4), "msgs_per_s": round(n_msgs / wall, 1),
            "sim_hours_per_s": round(instants * STEP_S / 3600.0 / wall, 2)}


def bench_core(stream, instants: int, folder: pathlib.Path) -> dict:
    topics = {t: ty for t, ty, _, _ in stream[:3]}
    t0 = time.perf_counter()
    with BagWriter(folder / "core", [TopicInfo(n, ty) for n, ty in topics.items()]) as w:
        for topic, _, t_ns, data in stream:
            w.write(topic, t_ns, data)
    write = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in (folder / "core").iterdir())
    raw = sum(len(d) for *_, d in stream)
    t0 = time.perf_counter()
    contents = read_bag(folder / "core")
    read = time.perf_counter() - t0
    assert contents.damage is None and len(contents.messages) == len(stream)
    return {"write": {**_rates(len(stream), instants, write),
                      "bag_bytes_per_message": round(size / len(stream), 1),
                      "compression_ratio": round(raw / size, 2)},
            "read": _rates(len(stream), instants, read)}


def bench_ros(stream, instants: int, folder: pathlib.Path, timeout_s: float = 300.0) -> dict:
    # ROS-free import path: ROS only for this half of the bench
    import rclpy
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from thermal_comp.bags.player_node import BagPlayerNode, use_fast_heartbeat
    from thermal_comp.bags.recorder_node import DEFAULT_TOPICS, BagRecorderNode, message_class
    use_fast_heartbeat()
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    ex = MultiThreadedExecutor(num_threads=2, context=ctx)
    spin = threading.Thread(target=ex.spin, daemon=True)
    figures: dict = {}
    try:
        rec = BagRecorderNode(context=ctx, parameter_overrides=[
            Parameter("output", value=str(folder / "ros")),
            Parameter("topics", value=["machine_state", "temperatures", "errors/ground_truth"])])
        pub_node = rclpy.create_node("bench_publisher", context=ctx)
        pubs = {f"/{name}": pub_node.create_publisher(message_class(ty), name, qos)
                for name, (ty, qos) in DEFAULT_TOPICS.items()
                if f"/{name}" in {t for t, *_ in stream[:3]}}
        ex.add_node(rec)
        ex.add_node(pub_node)
        spin.start()
        deadline = time.monotonic() + 30
        while any(p.get_subscription_count() < 1 for p in pubs.values()) and time.monotonic() < deadline:
            time.sleep(0.01)
        t0 = time.perf_counter()
        for topic, _, _, data in stream:
            pubs[topic].publish(data)
        deadline = time.monotonic() + timeout_s
        while rec.writer.message_count < len(stream) and time.monotonic() < deadline:
            time.sleep(0.001)
        wall = time.perf_counter() - t0
        got = rec.writer.message_count
        ex.remove_node(rec)
        rec.close()
        rec.destroy_node()
        figures["ros_record"] = {**_rates(got, instants * got // len(stream), wall),
                                 "lost": len(stream) - got}
        # replay the recorded bag to one subscriber per topic
        counts = {t: 0 for t in pubs}
        times: list[float] = []
        sub_node = rclpy.create_node("bench_subscriber", context=ctx)

        def counter(topic):
            def cb(_data):
                counts[topic] += 1
                times.append(time.perf_counter())
            return cb
        keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        for name, (ty, _qos) in DEFAULT_TOPICS.items():
            if f"/{name}" in counts:   # keep-all: the subscriber itself never overwrites a sample
                sub_node.create_subscription(message_class(ty), name, counter(f"/{name}"), keep_all, raw=True)
        ex.add_node(sub_node)
        player = BagPlayerNode(context=ctx, parameter_overrides=[
            Parameter("bag", value=str(folder / "ros")), Parameter("as_fast_as_possible", value=True),
            Parameter("wait_for_subscribers", value=1), Parameter("shutdown_when_done", value=False)])
        ex.add_node(player)
        player.result.done.wait(timeout_s)
        deadline = time.monotonic() + 30
        while sum(counts.values()) < player.result.published and time.monotonic() < deadline:
            time.sleep(0.001)
        received = sum(counts.values())
        wall = (times[-1] - times[0]) if len(times) > 1 else float("nan")
        figures["ros_replay"] = {**_rates(received, instants * received // len(stream), wall),
                                 "lost": player.result.published - received}
        player.close()
    finally:
        ex.shutdown()
        if ctx.ok():
            ctx.try_shutdown()
    return figures


def run(args) -> dict:
    quick = bool(getattr(args, "quick", False))
    instants = 200 if quick else 2000
    stream = synthetic_stream(instants)
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bench_bags_"))
    try:
        figures = {"instants": instants, "messages": len(stream), "step_s": STEP_S}
        figures.update(bench_core(stream, instants, folder))
        figures.update(bench_ros(stream[: 3 * min(instants, 500)], min(instants, 500), folder))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return figures
