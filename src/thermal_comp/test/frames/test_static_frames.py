"""Static frames: every twin preset's tree, the TFMessage type on the wire, and the node's /tf_static."""
from __future__ import annotations

import json
import pathlib
import sys

import pytest
import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from tf2_msgs.msg import TFMessage

from thermal_comp.frames.cli import main as frames_main
from thermal_comp.frames.description import load_description
from thermal_comp_common.frames import MACHINE_BASE_FRAME, FrameError, frame_tree, positions_in_root
from thermal_comp.frames.static_frames_node import STATIC_TF_QOS, StaticFramesNode
from thermal_twin.machine.presets import preset_names

#: ``ros2 topic info /tf --verbose`` on ROS 2 Jazzy: the type hash of tf2_msgs/msg/TFMessage
JAZZY_TFMESSAGE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


@pytest.mark.parametrize("name", preset_names())
def test_every_preset_puts_its_sensors_at_their_position(name):
    desc = load_description(name)
    pos = positions_in_root(frame_tree(desc))
    assert pos[MACHINE_BASE_FRAME] == (0.0, 0.0, 0.0)
    for node in desc.get("nodes", {}):
        assert f"body_{node}" in pos
    for sid, spec in desc.get("sensors", {}).items():
        if "position_mm" in spec:
            assert pos[f"sensor_{sid}"] == pytest.approx(tuple(v / 1000 for v in spec["position_mm"]))


def test_unknown_machine_is_named(tmp_path):
    with pytest.raises(FrameError, match="'no-such-machine': neither a file nor a twin preset"):
        load_description("no-such-machine")
    bad = tmp_path / "bad.yaml"
    bad.write_text("- a list\n")
    with pytest.raises(FrameError, match="no mapping"):
        load_description(str(bad))


def test_the_built_tfmessage_is_ros_own_type():
    share = pathlib.Path(sys.prefix) / "share" / "tf2_msgs" / "msg" / "TFMessage.json"
    described = json.loads(share.read_text())
    hashes = {d["type_name"]: d["hash_string"] for d in described["type_hashes"]}
    assert hashes["tf2_msgs/msg/TFMessage"] == JAZZY_TFMESSAGE_HASH


@pytest.mark.ros
def test_node_latches_the_tree_on_tf_static(ros_context, tmp_path):
    layout = tmp_path / "cell.yaml"
    layout.write_text(yaml.safe_dump({"nodes": {"table": {"position_mm": [0, 0, 100]}},
                                      "sensors": {"t1": {"of": "table", "position_mm": [10, 20, 130]},
                                                  "hall": {"position_mm": [-1000, 0, 0]}}}))
    node = StaticFramesNode(context=ros_context, parameter_overrides=[
        Parameter("machine", value=str(layout)), Parameter("frame_prefix", value="cell_a/")])
    late = rclpy.create_node("late_listener", context=ros_context)   # subscribes after the publish
    got = []
    late.create_subscription(TFMessage, "/tf_static", got.append, STATIC_TF_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(late)
    for _ in range(100):
        if got:
            break
        ex.spin_once(timeout_sec=0.1)
    assert len(got) == 1
    tf = {(t.header.frame_id, t.child_frame_id): t.transform.translation for t in got[0].transforms}
    assert set(tf) == {("cell_a/machine_base", "cell_a/body_table"), ("cell_a/body_table", "cell_a/sensor_t1"),
                       ("cell_a/machine_base", "cell_a/sensor_hall")}
    t1 = tf[("cell_a/body_table", "cell_a/sensor_t1")]
    assert (t1.x, t1.y, t1.z) == pytest.approx((0.01, 0.02, 0.03))
    ex.shutdown()
    late.destroy_node()
    node.destroy_node()


def test_frames_command_prints_the_tree_indented(capsys):
    assert frames_main(["nmv5000", "--prefix", "m1/"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "m1/machine_base"
    # a sensor on a body is indented under it, with its position in the root
    i = next(k for k, line in enumerate(lines) if line.strip().startswith("m1/sensor_ws_mwf"))
    assert lines[i - 1].strip().startswith("m1/body_mwf_tube") and lines[i].startswith("    ")
    assert "in root [+0.300, -0.250, +0.300]" in lines[i]
    assert frames_main(["no-such-machine"]) == 2
    assert "neither a file nor a twin preset" in capsys.readouterr().err
