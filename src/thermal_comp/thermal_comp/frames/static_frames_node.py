"""static_frames node: the machine's frames as static TF on ``/tf_static`` (REP 105).

The frame tree is :func:`thermal_comp_common.frames.frame_tree` of the twin preset or YAML file
named by ``machine`` (``machine_base`` -> ``body_<node>`` -> ``sensor_<id>`` at its
``position_mm``), published once as one ``tf2_msgs/TFMessage`` with the QoS of tf2's
StaticTransformBroadcaster (reliable, transient local, depth 1): a late subscriber such as rviz
or ``thermal-comp echo /tf_static --reliable`` still gets it.
Run: ``python -m thermal_comp.frames.static_frames_node --ros-args -p machine:=nmv5000``.
"""
from __future__ import annotations

from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from thermal_comp.frames.description import load_description
from thermal_comp_common.frames import FrameTransform, frame_tree
from thermal_comp_common.runtime.node_runtime import Param, declare_parameters, run_node

TOPIC_TF_STATIC = "/tf_static"   # absolute, as tf2 listens: a cell is a domain of its own
STATIC_TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
PARAMS = [
    Param("machine", "nmv5000", "twin preset (nmv5000, swiss-lathe, ...) or a YAML file with nodes/sensors "
          "and their position_mm"),
    Param("frame_prefix", "", "prefix of every frame id (e.g. 'cell_a/'), for several machines in one TF tree"),
]


def tf_message(transforms: list[FrameTransform], stamp) -> TFMessage:
    """One TFMessage holding every transform, stamped ``stamp`` (builtin_interfaces/Time)."""
    out = []
    for t in transforms:
        m = TransformStamped()
        m.header.stamp = stamp
        m.header.frame_id = t.parent
        m.child_frame_id = t.child
        m.transform.translation.x, m.transform.translation.y, m.transform.translation.z = t.translation_m
        r = m.transform.rotation
        r.x, r.y, r.z, r.w = t.rotation_xyzw
        out.append(m)
    return TFMessage(transforms=out)


class StaticFramesNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("static_frames", context=context, **kwargs)
        p = declare_parameters(self, PARAMS)
        self.transforms = frame_tree(load_description(p["machine"]), prefix=p["frame_prefix"])
        self.pub = self.create_publisher(TFMessage, TOPIC_TF_STATIC, STATIC_TF_QOS)
        self.pub.publish(tf_message(self.transforms, self.get_clock().now().to_msg()))
        self.get_logger().info(f"{len(self.transforms)} static frames of {p['machine']} on {TOPIC_TF_STATIC}")


def main(args=None):
    return run_node(StaticFramesNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
