"""temperature_publisher puts every sensor's status on /diagnostics (in process, no spinning:
the twin messages are handed to the node's callback)."""
from __future__ import annotations

import math

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)
from thermal_comp_common.runtime.node_runtime import s_to_stamp  # noqa: E402
from thermal_comp_msgs.msg import TemperatureArray  # noqa: E402

pytestmark = [pytest.mark.ros]

SENSORS = """
max_age_s: 25.0
sensors:
  - id: ambient
    range_degc: [0, 40]
  - id: spindle
    range_degc: [0, 60]
"""


def _twin(t, ambient, spindle):
    msg = TemperatureArray(sensor_ids=["ambient", "spindle"], temperatures_degc=[ambient, spindle],
                           status=[0, 0])
    msg.header.stamp = s_to_stamp(10.0 * t)
    return msg


def _statuses(node):
    return {s.name.split(": ", 1)[1]: (s.level, s.message) for s in node.diag.statuses()}


def test_each_sensor_status_is_on_diagnostics(tmp_path):
    from thermal_sensors.temperature_publisher_node import TemperaturePublisher
    cfg = tmp_path / "sensors.yaml"
    cfg.write_text(SENSORS)
    ctx_args = ["x", "--ros-args", "-p", "source:=twin", "-p", f"sensor_config:={cfg}"]
    ctx = rclpy.context.Context()
    rclpy.init(args=ctx_args, context=ctx)
    node = TemperaturePublisher(context=ctx)
    try:
        for k, (amb, spi) in enumerate([(20.0, 30.0), (20.5, 99.0), (21.0, math.nan), (21.5, 31.0)]):
            node._on_twin(_twin(k, amb, spi))
            st = _statuses(node)
            assert st["sensor ambient"] == (b"\x00", "ok")
            if k == 0 or k == 3:
                assert st["sensor spindle"] == (b"\x00", "ok")
                assert st["sensors"] == (b"\x00", "all sensors ok")
            elif k == 1:
                level, text = st["sensor spindle"]
                assert level == b"\x01" and text.startswith("out_of_range")
                assert st["sensors"] == (b"\x01", "1 of 2 sensors not ok")
            else:
                level, text = st["sensor spindle"]
                assert level == b"\x02" and text.startswith("failed")
        assert node.diag.published >= 4       # each change went out at once
    finally:
        node.destroy_node()
        ctx.try_shutdown()
