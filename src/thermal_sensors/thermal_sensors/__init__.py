"""Temperature sources (twin, CSV/bag replay, Modbus RTD modules), their configuration,
gain/offset correction and status; ROS-free (the publisher node lives in
``thermal_sensors.temperature_publisher_node``). See docs/sensors.md."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "sensor_config": ["SensorConfig", "SensorConfigError", "load_sensor_config", "parse_sensor_config",
                      "resolve_sensor_config"],
    "temperature_source": ["RawSample", "TemperatureSource"],
    "twin_source": ["TwinSource"],
    "replay_source": ["ReplaySource"],
    "modbus_source": ["ModbusLink", "ModbusSource"],
    "temperature_frame": ["TemperatureFrame", "TemperatureFrameBuilder"],
    "sensor_status": ["SensorStatus", "SensorStatusTracker"],
    "gain_offset": ["GainOffset"],
    "rtd_emulator": ["RtdEmulator"],
})
