"""rtd_twin_feed: serve the twin's live sensor readings as emulated Modbus RTD modules.

Subscribes to machine_sim's ``twin/sensor_readings`` and writes each configured sensor
(matched by ``channel``) into an :class:`~thermal_sensors.rtd_emulator.RtdEmulator` that
serves the sensor YAML's modules, so a Modbus client (the ``modbus`` source, a PLC, a
logger) reads the twin as if it were real hardware. A twin sensor that is missing, NaN or
FAILED is served as the module's fault code.

Run: ``thermal-comp rtd-emulator --config YAML --twin`` or
``python -m thermal_sensors.rtd_twin_feed_node --ros-args -p sensor_config:=YAML``.
"""
from __future__ import annotations

import math

from rclpy.node import Node

from thermal_comp_common.runtime.node_runtime import (SENSOR_QOS, TOPIC_TWIN_SENSORS, Param, declare_parameters,
                                       run_node)
from thermal_comp_msgs.msg import TemperatureArray
from thermal_sensors.rtd_emulator import RtdEmulator
from thermal_sensors.sensor_config import load_sensor_config, resolve_sensor_config
from thermal_sensors.twin_source import TWIN_STATUS_FAILED

PARAMS = [Param("sensor_config", "", "sensor YAML with sensors[].modbus and modbus.modules")]


class RtdTwinFeed(Node):
    def __init__(self, context=None, emulator: RtdEmulator | None = None):
        super().__init__("rtd_twin_feed", context=context)
        p = declare_parameters(self, PARAMS)
        if emulator is None:
            if not p["sensor_config"]:
                raise ValueError("parameter 'sensor_config': required")
            emulator = RtdEmulator(load_sensor_config(resolve_sensor_config(p["sensor_config"])))
            emulator.start()
            self._owns_emulator = True
        else:
            self._owns_emulator = False
        self.emulator = emulator
        self.updates = 0
        self.create_subscription(TemperatureArray, TOPIC_TWIN_SENSORS, self._on_readings, SENSOR_QOS)
        for m in emulator.config.modules:
            where = m.serial_port if m.transport == "rtu" else f"{m.host}:{m.port}"
            self.get_logger().info(f"module {m.name} ({m.transport}, unit {m.unit_id}) on {where}")

    def _on_readings(self, msg: TemperatureArray) -> None:
        index = {sid: k for k, sid in enumerate(msg.sensor_ids)}
        values = {}
        for spec in self.emulator.config.sensors:
            k = index.get(spec.channel)
            ok = (k is not None and k < len(msg.temperatures_degc)
                  and not (k < len(msg.status) and msg.status[k] == TWIN_STATUS_FAILED))
            values[spec.id] = float(msg.temperatures_degc[k]) if ok else math.nan
        self.emulator.set_temperatures(values)
        self.updates += 1

    def close(self) -> None:
        if self._owns_emulator:
            self.emulator.stop()


def main(args=None) -> int:
    return run_node(RtdTwinFeed, args)


if __name__ == "__main__":
    raise SystemExit(main())
