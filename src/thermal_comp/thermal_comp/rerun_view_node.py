"""rerun_view node: logs every thermal-comp topic of the cell to rerun as it arrives.

Subscribes to the default topics of the recorder (same types and QoS, so reliable
publishers are matched and latched model status arrives at once) and hands each message to
:class:`thermal_comp.rerun_logging.RerunLogger`, stamped with its header time. Started by
``thermal-comp view`` without a bag (the rerun sinks are set up there).
"""
from __future__ import annotations

from rclpy.node import Node

from thermal_comp import node_runtime as rt
from thermal_comp.bag_recorder_node import DEFAULT_TOPICS, message_class
from thermal_comp.rerun_logging import RerunLogger


class RerunViewNode(Node):
    def __init__(self, recording, layout=None, context=None, **kwargs):
        super().__init__("rerun_view", context=context, **kwargs)
        self.logger_ = RerunLogger(recording, layout)
        self.recording = recording
        for name, (type_name, qos) in DEFAULT_TOPICS.items():
            topic = self.resolve_topic_name(name)
            self.create_subscription(message_class(type_name), name,
                                     self._callback_for(topic, type_name), qos)
        self.get_logger().info("logging topics to rerun: " + ", ".join(DEFAULT_TOPICS))

    def _callback_for(self, topic: str, type_name: str):
        def on_message(msg) -> None:
            stamp = msg.header.stamp
            t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            if t_ns == 0:
                t_ns = self.get_clock().now().nanoseconds
            self.logger_.log(topic, type_name, msg, t_ns)
        return on_message

    def close(self) -> None:
        self.recording.flush(timeout_sec=30.0)


def main(recording, layout=None, args=None) -> int:
    def factory(context):
        return RerunViewNode(recording, layout, context=context)
    factory.__name__ = "rerun_view"
    return rt.run_node(factory, args)
