"""Test node: publishes a TemperatureArray on `temperatures` at a fixed period (counter values)."""
from __future__ import annotations

import sys

from rclpy.node import Node

from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, TOPIC_TEMPERATURES, Param, declare_parameters, run_node
from thermal_comp_msgs.msg import TemperatureArray


class TemperatureTalker(Node):
    def __init__(self, context=None):
        super().__init__("temperature_talker", context=context)
        p = declare_parameters(self, [
            Param("period_s", 0.05, "publishing period", lo=0.001, hi=10.0),
            Param("sensor_ids", ["s1", "s2"], "sensor ids"),
        ])
        self.sensor_ids = list(p["sensor_ids"])
        self.count = 0
        self.pub = self.create_publisher(TemperatureArray, TOPIC_TEMPERATURES, SENSOR_QOS)
        self.create_timer(p["period_s"], self.tick)

    def tick(self):
        self.count += 1
        m = TemperatureArray()
        m.header.stamp = self.get_clock().now().to_msg()
        m.sensor_ids = self.sensor_ids
        m.temperatures_degc = [20.0 + self.count + 0.5 * i for i in range(len(self.sensor_ids))]
        m.status = [TemperatureArray.STATUS_OK] * len(self.sensor_ids)
        self.pub.publish(m)


def main(args=None):
    return run_node(TemperatureTalker, args)


if __name__ == "__main__":
    sys.exit(main())
