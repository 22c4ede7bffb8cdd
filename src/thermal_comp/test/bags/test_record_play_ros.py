"""End to end over ROS: the recorder node records what is published, a killed recorder keeps
what it flushed, and the player re-publishes a bag byte for byte with /clock."""
import pathlib
import signal
import threading
import time

import pytest
import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor
from rosgraph_msgs.msg import Clock
from thermal_comp_msgs.msg import MachineState, TemperatureArray, ThermalErrors

from bags_helpers import small_recording_csv, spawn, stop, wait_for
from thermal_comp_common.runtime import node_runtime as rt
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.csv_to_bag import csv_to_bag
from thermal_comp.bags import record_cli, recorder_node

pytestmark = [pytest.mark.ros, pytest.mark.slow]


class Spinner:
    """Spin a test node in a background thread (callbacks fill plain lists)."""

    def __init__(self, ctx, name):
        self.node = rclpy.create_node(name, context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.running = True
        self.thread.start()

    def _spin(self):
        while self.running and self.ex.context.ok():
            self.ex.spin_once(timeout_sec=0.05)

    def close(self):
        self.running = False
        self.thread.join(timeout=5)
        self.ex.remove_node(self.node)
        self.node.destroy_node()


def _temps(k: int) -> TemperatureArray:
    m = TemperatureArray()
    m.header.stamp = rt.s_to_stamp(100.0 + 15.0 * k)
    m.sensor_ids = ["t1", "t2"]
    m.temperatures_degc = [20.0 + 0.1 * k, float("nan") if k == 3 else 21.0]
    m.status = [0, 3 if k == 3 else 0]
    return m


def _meta_count(bag) -> int:
    try:
        info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, TypeError, KeyError, yaml.YAMLError):
        return -1
    return info["message_count"]


def _record(tmp_path, ros_context, n: int, sig, *extra):
    bag = tmp_path / "rec"
    proc = spawn(["-m", "thermal_comp.bags.record_cli", str(bag), "temperatures", "machine_state",
                  "--flush-period", "0.1", *extra])
    s = Spinner(ros_context, "test_publisher")
    try:
        pub = s.node.create_publisher(TemperatureArray, rt.TOPIC_TEMPERATURES, rt.SENSOR_QOS)
        wait_for(lambda: pub.get_subscription_count() >= 1 or proc.poll() is not None, 30,
                 "the recorder to subscribe")
        assert proc.poll() is None, proc.communicate()[0]
        for k in range(n):   # published at once after matching: nothing may be lost
            pub.publish(_temps(k))
        wait_for(lambda: _meta_count(bag) >= n, 30, f"{n} messages flushed to {bag}")
        out = stop(proc, sig)
    finally:
        s.close()
    return bag, proc.returncode, out


def test_record_and_the_recorder_node_share_the_receive_time_default():
    """One timestamp default, as rosbag2: the bag's log time is the receive time."""
    assert record_cli.build_parser().parse_args(["out"]).timestamps == "receive"
    (param,) = [p for p in recorder_node.PARAMS if p.name == "timestamps"]
    assert param.default == recorder_node.DEFAULT_TIMESTAMPS == "receive"


def test_recorder_logs_receive_time_and_keeps_the_header_stamp(tmp_path, ros_context):
    wall0 = time.time_ns()
    bag, code, out = _record(tmp_path, ros_context, 5, signal.SIGINT)
    assert code == 0, out
    c = read_bag(bag)
    logs = [m.log_time_ns for m in c.messages]
    assert logs == sorted(logs) and wall0 <= logs[0] and logs[-1] <= time.time_ns()
    assert [m.stamp_ns for m in c.messages] == [int((100 + 15 * k) * 1e9) for k in range(5)]


def test_recorder_records_everything_published_after_start(tmp_path, ros_context):
    bag, code, out = _record(tmp_path, ros_context, 25, signal.SIGINT, "--timestamps", "header")
    assert code == 0, out
    c = read_bag(bag)
    assert c.damage is None
    assert c.topics["/temperatures"].type == "thermal_comp_msgs/msg/TemperatureArray"
    assert c.topics["/machine_state"].message_count == 0
    from rclpy.serialization import deserialize_message
    got = [deserialize_message(m.data, TemperatureArray) for m in c.messages]
    assert [round(rt.stamp_to_s(m.header.stamp), 3) for m in got] == [100.0 + 15.0 * k for k in range(25)]
    assert [m.log_time_ns for m in c.messages] == [int((100 + 15 * k) * 1e9) for k in range(25)]
    assert got[3].status[1] == 3 and got[24].temperatures_degc[0] == pytest.approx(22.4)
    # the recorded bag is a rosbag2 bag for the ecosystem's readers too
    from rosbags.rosbag2 import Reader
    from thermal_comp_common.bags import msg_definitions as md
    with Reader(bag) as reader:
        assert reader.message_count == 25
        conn = next(c for c in reader.connections if c.topic == "/temperatures")
        assert conn.digest == md.installed_type_hash("thermal_comp_msgs/msg/TemperatureArray")
        assert [c.topic for c in reader.connections] == ["/temperatures", "/machine_state"]


def test_killed_recorder_keeps_what_it_flushed(tmp_path, ros_context):
    bag, code, out = _record(tmp_path, ros_context, 12, signal.SIGKILL)
    assert code == -signal.SIGKILL
    c = read_bag(bag)
    assert len([m for m in c.messages if m.topic == "/temperatures"]) == 12
    assert c.damage and "footer" in c.damage


def _subscribe_all(s: Spinner, received: dict):
    for topic, cls, qos in ((rt.TOPIC_TEMPERATURES, TemperatureArray, rt.SENSOR_QOS),
                            (rt.TOPIC_MACHINE_STATE, MachineState, rt.SENSOR_QOS),
                            (rt.TOPIC_ERRORS_TRUE, ThermalErrors, rt.EVENT_QOS)):
        received["/" + topic] = []
        s.node.create_subscription(cls, topic, received["/" + topic].append, qos, raw=True)
    received["/clock"] = []
    s.node.create_subscription(Clock, "/clock", lambda m: received["/clock"].append(
        m.clock.sec * 10**9 + m.clock.nanosec), 100)


def test_player_republishes_every_message_as_fast_as_possible(tmp_path, ros_context):
    bag = tmp_path / "bag"
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=60), bag)
    contents = read_bag(bag)
    s = Spinner(ros_context, "test_listener")
    received: dict = {}
    try:
        _subscribe_all(s, received)
        proc = spawn(["-m", "thermal_comp.bags.play_cli", str(bag), "--as-fast-as-possible",
                      "--wait-for-subscribers", "1"])
        out = proc.communicate(timeout=60)[0]
        assert proc.returncode == 0, out
        wait_for(lambda: all(len(received[t]) == 60 for t in received if t != "/clock"), 10,
                 "all replayed messages")
    finally:
        s.close()
    for topic in ("/temperatures", "/machine_state", "/errors/ground_truth"):
        want = [m.data for m in contents.messages if m.topic == topic]
        assert len(received[topic]) == len(want)
        for got, data in zip(received[topic], want):
            # the same bytes; the middleware may append CDR alignment padding (< 4 zero bytes)
            assert got[:len(data)] == data and set(got[len(data):]) <= {0} and len(got) - len(data) < 4
    assert received["/clock"] == sorted(received["/clock"])
    assert set(received["/clock"]) == {m.log_time_ns for m in contents.messages}
    assert "replayed 180 messages in 60 instants" in out


def test_player_at_a_rate_drives_clock_between_messages(tmp_path, ros_context):
    bag = tmp_path / "bag"
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=10), bag)   # 540 s of bag time
    s = Spinner(ros_context, "test_listener_rate")
    received: dict = {}
    try:
        _subscribe_all(s, received)
        proc = spawn(["-m", "thermal_comp.bags.play_cli", str(bag), "--rate", "900",
                      "--wait-for-subscribers", "1", "--clock-hz", "50"])
        out = proc.communicate(timeout=60)[0]
        assert proc.returncode == 0, out
        wait_for(lambda: len(received["/temperatures"]) == 10, 10, "10 temperatures")
    finally:
        s.close()
    clock = received["/clock"]
    assert clock == sorted(clock)
    stamps = {k * 60 * 10**9 for k in range(10)}
    assert stamps <= set(clock)
    assert len(set(clock) - stamps) > 0     # /clock also advanced between the messages


def test_player_replays_a_truncated_bag_up_to_the_damage(tmp_path, ros_context):
    bag = tmp_path / "bag"
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=100), bag, chunk_bytes=2048)
    f = bag / "bag_0.mcap"
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    kept = read_bag(bag)
    assert 0 < len(kept.messages) < 300
    proc = spawn(["-m", "thermal_comp.bags.play_cli", str(bag), "--as-fast-as-possible"])
    out = proc.communicate(timeout=60)[0]
    assert proc.returncode == 3, out
    assert f"replayed {len(kept.messages)} messages" in out
    assert "bag damaged, replay stopped there" in out and "stopped at byte" in out
    assert "Traceback" not in out


def test_play_and_record_reject_bad_arguments(tmp_path):
    for args, text in ((["-m", "thermal_comp.bags.play_cli", str(tmp_path / "nope")], "no such bag"),
                       (["-m", "thermal_comp.bags.play_cli", str(tmp_path), "--rate", "0"], "--rate 0.0"),
                       (["-m", "thermal_comp.bags.record_cli", str(tmp_path / "x"), "unknown_topic"],
                        "'unknown_topic' is not a known topic")):
        proc = spawn(args)
        out = proc.communicate(timeout=60)[0]
        assert proc.returncode == 2 and text in out and "Traceback" not in out, out


def test_lockstep_participant_paces_the_replay_so_a_depth_one_subscriber_misses_nothing(tmp_path, ros_context):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thermal_comp_msgs.msg import SimSync
    bag = tmp_path / "bag"
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=40), bag)
    s = Spinner(ros_context, "test_participant")
    got = []
    sync = s.node.create_publisher(SimSync, rt.TOPIC_SIM_SYNC, rt.EVENT_QOS)

    def on_temps(msg):   # a participant that acknowledges each instant once it has its data
        got.append(rt.stamp_to_s(msg.header.stamp))
        ack = SimSync()
        ack.header.stamp = msg.header.stamp
        ack.node_name = "test_participant"
        ack.processed_until = msg.header.stamp
        sync.publish(ack)

    s.node.create_subscription(TemperatureArray, rt.TOPIC_TEMPERATURES, on_temps,
                               QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    try:
        proc = spawn(["-m", "thermal_comp.bags.play_cli", str(bag), "--as-fast-as-possible", "--topics",
                      "/temperatures", "--wait-for-subscribers", "1", "--lockstep", "test_participant"])
        out = proc.communicate(timeout=60)[0]
        assert proc.returncode == 0, out
    finally:
        s.close()
    assert got == [60.0 * k for k in range(40)]


def test_play_into_record_reproduces_the_bag(tmp_path):
    """play -> record round trip: same topics, times and bytes (up to CDR padding). Within one
    instant, messages of different topics may arrive in any order (separate DDS topics)."""
    src = tmp_path / "src"
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=50), src)
    original = read_bag(src)
    copy = tmp_path / "copy"
    rec = spawn(["-m", "thermal_comp.bags.record_cli", str(copy), "temperatures", "machine_state",
                 "errors/ground_truth", "--flush-period", "0.1", "--timestamps", "header"])
    try:
        player = spawn(["-m", "thermal_comp.bags.play_cli", str(src), "--as-fast-as-possible",
                        "--wait-for-subscribers", "1"])
        out = player.communicate(timeout=60)[0]
        assert player.returncode == 0, out
        wait_for(lambda: _meta_count(copy) >= len(original.messages), 30, "the copy to hold every message")
    finally:
        rec_out = stop(rec)
    assert rec.returncode == 0, rec_out
    again = read_bag(copy)
    assert again.damage is None
    def key(m):
        return (m.log_time_ns, m.topic)
    got, want = sorted(again.messages, key=key), sorted(original.messages, key=key)
    assert [key(m) for m in got] == [key(m) for m in want]
    for a, b in zip(got, want):
        assert a.data[:len(b.data)] == b.data and set(a.data[len(b.data):]) <= {0}


GRAPH_BAG = pathlib.Path(__file__).resolve().parents[4] / "bags" / "graph_nmv5000_load_case_A_12h"


@pytest.mark.parametrize("pace", [["--as-fast-as-possible"], ["--rate", "1000000"]], ids=["fastest", "rate_1e6"])
def test_play_into_record_loses_nothing_on_any_topic(tmp_path, pace):
    """A demo graph's bag (two model_status at some instants, on a latched depth-1 topic) played at
    the player's fastest pace and at a rate it cannot keep: messages out / in = 1 per topic."""
    original = read_bag(GRAPH_BAG)
    copy = tmp_path / "copy"
    topics = [f"{name}:{spec.type}" for name, spec in original.topics.items()]
    rec = spawn(["-m", "thermal_comp.bags.record_cli", str(copy), *topics, "--flush-period", "0.2"])
    try:
        player = spawn(["-m", "thermal_comp.bags.play_cli", str(GRAPH_BAG), *pace, "--wait-for-subscribers", "1"])
        out = player.communicate(timeout=240)[0]
        assert player.returncode == 0, out
        wait_for(lambda: _meta_count(copy) >= len(original.messages), 60, "the copy to hold every message")
    finally:
        rec_out = stop(rec)
    assert rec.returncode == 0, rec_out
    again = read_bag(copy)
    ratios = {}
    for name, spec in original.topics.items():
        got = sum(1 for m in again.messages if m.topic == name)
        ratios[name] = got / spec.message_count
        print(f"play {' '.join(pace)} -> record: {name}: out {spec.message_count} in {got} "
              f"ratio {ratios[name]:.3f}")
    print(next(ln for ln in out.splitlines() if "replayed" in ln))
    assert all(r == 1.0 for r in ratios.values()), ratios
    assert sorted(m.data for m in again.messages) == sorted(m.data for m in original.messages)
