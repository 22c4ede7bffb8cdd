"""Test node: subscribes to `temperatures` and prints one line per message received."""
from __future__ import annotations

import sys

from rclpy.node import Node

from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, TOPIC_TEMPERATURES, run_node
from thermal_comp_msgs.msg import TemperatureArray


class TemperatureListener(Node):
    def __init__(self, context=None):
        super().__init__("temperature_listener", context=context)
        self.create_subscription(TemperatureArray, TOPIC_TEMPERATURES, self.on_msg, SENSOR_QOS)

    def on_msg(self, m: TemperatureArray):
        print(f"received {m.sensor_ids[0]}={m.temperatures_degc[0]:.1f}", flush=True)


def main(args=None):
    return run_node(TemperatureListener, args)


if __name__ == "__main__":
    sys.exit(main())
