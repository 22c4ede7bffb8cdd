"""Our bags are genuine rosbag2 MCAP bags: rosbags and mcap-ros2-support read them back."""
import math
import pathlib

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from bags_helpers import small_recording_csv
from thermal_comp_common.bags import msg_definitions as md
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.writer import BagWriteError, BagWriter, TopicInfo, stamp_from_cdr
from thermal_comp_common.bags.csv_to_bag import csv_to_bag
from thermal_comp_common.recording_csv import read_recording_csv


@pytest.fixture
def bag(tmp_path) -> pathlib.Path:
    csv = small_recording_csv(tmp_path / "rec.csv")
    csv_to_bag(csv, tmp_path / "bag")
    return tmp_path / "bag"


def test_rosbags_reader_reads_types_hashes_and_values(bag, tmp_path):
    rec = read_recording_csv(tmp_path / "rec.csv")
    store = md.typestore()
    with Reader(bag) as reader:
        topics = {c.topic: c for c in reader.connections}
        assert set(topics) == {"/machine_state", "/temperatures", "/errors/ground_truth"}
        for c in reader.connections:
            assert c.digest == md.installed_type_hash(c.msgtype)
        assert reader.message_count == 3 * len(rec)
        temps = [store.deserialize_cdr(raw, c.msgtype)
                 for c, t, raw in reader.messages(connections=[topics["/temperatures"]])]
    assert [m.sensor_ids for m in temps[:1]] == [["ambient", "c_motor", "ws_mwf"]]
    got = np.array([m.temperatures_degc for m in temps])
    want = np.column_stack([rec.columns[c] for c in ("ambient_c", "c_motor_c", "ws_mwf_c")])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, equal_nan=True)
    assert temps[5].status[2] == 3 and math.isnan(temps[5].temperatures_degc[2])   # FAILED
    assert temps[5].status[0] == 0


def test_mcap_ros2_support_decodes_our_custom_types(bag):
    mcap_file = next(bag.glob("*.mcap"))
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert all(c.message_encoding == "cdr" for c in summary.channels.values())
        assert all(c.metadata["topic_type_hash"].startswith("RIHS01_") for c in summary.channels.values())
        assert summary.statistics.chunk_count >= 1
        seen = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, decoded)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert seen["/errors/ground_truth"].component_names == ["E_X0C", "E_A0C"]
    assert list(seen["/errors/ground_truth"].units) == [0, 1]
    assert seen["/errors/ground_truth"].source == 2
    assert seen["/machine_state"].rotary_axis_names == ["C"]
    assert "serialized_metadata" in meta["rosbag2"]


def test_chunks_are_zstd_compressed(bag):
    mcap_file = next(bag.glob("*.mcap"))
    with open(mcap_file, "rb") as f:
        summary = make_reader(f).get_summary()
    assert {ci.compression for ci in summary.chunk_indexes} == {"zstd"}


def test_metadata_yaml_is_rosbag2_version_9(bag):
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["bag_0.mcap"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}
    assert counts == {"/machine_state": 40, "/temperatures": 40, "/errors/ground_truth": 40}
    assert info["message_count"] == 120
    assert info["duration"]["nanoseconds"] == 39 * 60 * 10**9


def test_own_reader_gives_messages_in_time_order(bag):
    c = read_bag(bag)
    assert c.damage is None
    times = [m.log_time_ns for m in c.messages]
    assert times == sorted(times)
    assert [m.topic for m in c.messages[:3]] == ["/machine_state", "/temperatures", "/errors/ground_truth"]
    assert all(stamp_from_cdr(m.data) == m.log_time_ns for m in c.messages)


def test_writer_refuses_existing_folder_and_unknown_topics(tmp_path):
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagWriteError, match="exists already"):
        BagWriter(tmp_path / "exists")
    with BagWriter(tmp_path / "b", [TopicInfo("/temperatures", "thermal_comp_msgs/TemperatureArray")]) as w:
        with pytest.raises(BagWriteError, match="'/offsets' is not registered"):
            w.write("/offsets", 0, b"\x00\x01\x00\x00")
        with pytest.raises(BagWriteError, match="already recorded as"):
            w.add_topic(TopicInfo("/temperatures", "thermal_comp_msgs/ThermalErrors"))
    with pytest.raises(BagWriteError, match="fully resolved"):
        TopicInfo("temperatures", "thermal_comp_msgs/TemperatureArray")


def test_flush_makes_a_crashed_bag_readable_up_to_the_last_chunk(tmp_path):
    store = md.typestore()
    T = store.types["thermal_comp_msgs/msg/SimSync"]
    Time = store.types["builtin_interfaces/msg/Time"]
    H = store.types["std_msgs/msg/Header"]

    def data(k):
        return bytes(store.serialize_cdr(T(header=H(stamp=Time(sec=k, nanosec=0), frame_id=""),
                                            node_name="n", processed_until=Time(sec=k, nanosec=0)),
                                          "thermal_comp_msgs/msg/SimSync"))

    w = BagWriter(tmp_path / "b", [TopicInfo("/sim_sync", "thermal_comp_msgs/SimSync")])
    for k in range(10):
        w.write("/sim_sync", k * 10**9, data(k))
    w.flush()
    for k in range(10, 15):
        w.write("/sim_sync", k * 10**9, data(k))
    # simulated crash: the process dies without close(); the open chunk is lost
    w._stream.close()
    c = read_bag(tmp_path / "b")
    assert [m.log_time_ns // 10**9 for m in c.messages] == list(range(10))
    assert "without MCAP footer" in c.damage or "past the end" in c.damage
    info = yaml.safe_load((tmp_path / "b" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == 10
