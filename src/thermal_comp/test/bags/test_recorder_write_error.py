"""Over ROS: a recorder whose writes fail (here a file-size limit, EFBIG; a full disk is ENOSPC,
test_bag_disk_full) stops with exit code 1 and one error line, no traceback, and leaves a bag
that reads up to what was on disk, marked incomplete."""
import resource
import signal

import pytest
from thermal_comp_msgs.msg import TemperatureArray

from bags_helpers import spawn, stop, wait_for
from test_record_play_ros import Spinner, _meta_count
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.runtime import node_runtime as rt

pytestmark = [pytest.mark.ros, pytest.mark.slow]

FILE_LIMIT = 120_000      # bytes per file: above the bag's reserve and metadata, below 8 messages
SENSORS = 1000


def _limit_file_size():  # runs in the child before exec
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)    # a write beyond the limit fails with EFBIG instead
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))


def _big(k: int) -> TemperatureArray:
    m = TemperatureArray()
    m.header.stamp = rt.s_to_stamp(60.0 * (k + 1))
    m.sensor_ids = [f"sensor_{i:04d}" for i in range(SENSORS)]
    m.temperatures_degc = [20.0 + 1e-3 * (i * 7 + k) for i in range(SENSORS)]
    m.status = [0] * SENSORS
    return m


def test_a_write_error_stops_the_recorder_in_one_line_and_keeps_the_bag(tmp_path, ros_context):
    bag = tmp_path / "rec"
    proc = spawn(["-m", "thermal_comp.bags.record_cli", str(bag), "temperatures", "--compression", "none",
                  "--flush-period", "0.1"], preexec_fn=_limit_file_size)
    s = Spinner(ros_context, "test_publisher")
    try:
        pub = s.node.create_publisher(TemperatureArray, rt.TOPIC_TEMPERATURES, rt.SENSOR_QOS)
        wait_for(lambda: pub.get_subscription_count() >= 1 or proc.poll() is not None, 30,
                 "the recorder to subscribe")
        assert proc.poll() is None, proc.communicate()[0]
        for k in range(2):
            pub.publish(_big(k))
        wait_for(lambda: _meta_count(bag) >= 2, 30, "2 messages flushed")
        for k in range(2, 10):
            pub.publish(_big(k))
        wait_for(lambda: proc.poll() is not None, 30, "the recorder to stop on the write error")
        out = stop(proc)
    finally:
        s.close()
    assert proc.returncode == 1, out
    assert "Traceback" not in out, out
    errors = [line for line in out.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "recording stopped:" in errors[0] and "(EFBIG)" in errors[0], out
    assert "marked incomplete" in errors[0], out
    contents = read_bag(bag)
    assert 2 <= len(contents.messages) < 10
    assert "incomplete" in contents.damage and "EFBIG" in contents.damage, contents.damage
