"""rerun_view node: logs every thermal-comp topic of the cell to rerun as it arrives.

Subscribes to the default topics of the recorder (same types and QoS, so reliable
publishers are matched and the latched model status arrives at once) and to the graph's
health, ``/diagnostics`` and ``/rosout``, and hands each message to
:class:`thermal_comp.view.rerun_logging.RerunLogger`, stamped with its header time (a Log's stamp).
Run: ``python -m thermal_comp.view.rerun_view_node --ros-args -p rrd:=out/live.rrd`` (parameters
below; default: a spawned native viewer), or ``thermal-comp view`` without a bag.
"""
from __future__ import annotations

from rclpy.node import Node

from thermal_comp_common.runtime import node_runtime as rt
from thermal_comp.bags.recorder_node import DEFAULT_TOPICS, HEALTH_TOPICS, message_class
from thermal_comp.view.blueprint import default_blueprint
from thermal_comp.view.rerun_logging import RerunLogger, resolve_layout
from thermal_comp.view.rerun_sinks import RerunOutput, open_output


class RerunViewNode(Node):
    """``output``: an already opened rerun output (from ``thermal-comp view``); else the
    node's parameters choose the sinks."""

    def __init__(self, context=None, output: RerunOutput | None = None, layout=None, **kwargs):
        super().__init__("rerun_view", context=context, **kwargs)
        p = rt.declare_parameters(self, [
            rt.Param("spawn", True, "spawn the native rerun viewer (needs a display)"),
            rt.Param("rrd", "", "write an .rrd file here (empty: none)"),
            rt.Param("serve_web", False, "serve rerun's web viewer on localhost"),
            rt.Param("web_port", 9090, "web viewer port", lo=1, hi=65535),
            rt.Param("grpc_port", 9876, "rerun gRPC port", lo=1, hi=65535),
            rt.Param("layout", "", "sensor layout YAML or twin preset (empty: the preset whose "
                     "sensors match, else a schematic ring)"),
        ])
        if layout is None and p["layout"]:
            layout = resolve_layout(p["layout"])
        if output is None:
            ns = self.get_namespace()
            output = open_output(rrd=p["rrd"] or None, spawn=p["spawn"], serve_web=p["serve_web"],
                                 web_port=p["web_port"], grpc_port=p["grpc_port"],
                                 blueprint=default_blueprint(ns if ns != "/" else ""))
            if output.web_url:
                self.get_logger().info(f"rerun web viewer: {output.web_url}")
        self.output = output
        self.logger_ = RerunLogger(output.recording, layout)
        topics = {**DEFAULT_TOPICS, **HEALTH_TOPICS}
        for name, (type_name, qos) in topics.items():
            topic = self.resolve_topic_name(name)
            self.create_subscription(message_class(type_name), name,
                                     self._callback_for(topic, type_name), qos)
        self.get_logger().info("logging topics to rerun: " + ", ".join(topics))

    def _callback_for(self, topic: str, type_name: str):
        def on_message(msg) -> None:
            stamp = msg.header.stamp if hasattr(msg, "header") else msg.stamp
            t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            if t_ns == 0:
                t_ns = self.get_clock().now().nanoseconds
            self.logger_.log(topic, type_name, msg, t_ns)
        return on_message

    def close(self) -> None:
        self.output.close()


def run(output: RerunOutput, layout=None, args=None) -> int:
    """Run the node on an output opened by the caller (``thermal-comp view``)."""
    def factory(context):
        return RerunViewNode(context=context, output=output, layout=layout)
    factory.__name__ = "rerun_view"
    return rt.run_node(factory, args)


def main(args=None) -> int:
    return rt.run_node(RerunViewNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
