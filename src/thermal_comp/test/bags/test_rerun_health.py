"""Health in rerun: /diagnostics statuses and /rosout lines become text logs with levels
(thermal_comp.view.rerun_logging), and the live view subscribes to both."""
import subprocess
import sys

import pytest

from bags_helpers import stop, wait_for
from test_rerun_columns import _Capture
from test_rerun_view import _entities, _env, _synthetic_messages
from thermal_comp.view.rerun_logging import RerunLogger
from thermal_comp_common.bags import msg_definitions as md
def _diagnostics(store, t, level, message):
    T, H = store.types["builtin_interfaces/msg/Time"], store.types["std_msgs/msg/Header"]
    S, KV = store.types["diagnostic_msgs/msg/DiagnosticStatus"], store.types["diagnostic_msgs/msg/KeyValue"]
    return store.types["diagnostic_msgs/msg/DiagnosticArray"](
        header=H(stamp=T(sec=t, nanosec=0), frame_id=""),
        status=[S(level=level, name="sensors: sensor spindle", message=message, hardware_id="nmv5000",
                  values=[KV(key="temperature_degc", value="25.0")])])


def _log(store, t, level, name, text):
    T = store.types["builtin_interfaces/msg/Time"]
    return store.types["rcl_interfaces/msg/Log"](stamp=T(sec=t, nanosec=0), level=level, name=name, msg=text,
                                                 file="f.py", function="f", line=1)


SPINDLE = "diagnostics/sensors/sensor_spindle"     # status "sensors: sensor spindle"


@pytest.mark.parametrize("columnar", [False, True])
def test_diagnostics_and_rosout_become_text_logs_with_levels(columnar):
    store = md.typestore()
    rec = _Capture()
    logger = RerunLogger(rec, columnar=columnar)
    for t, level, message in ((0, 0, "ok"), (1, 0, "ok"), (2, 1, "stale: no reading for 30 s")):
        logger.log("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", _diagnostics(store, t, level, message),
                   t * 10**9)
    wall = 1_795_808_975                      # log lines carry the wall clock, data the simulated one
    logger.log("/rosout", "rcl_interfaces/msg/Log", _log(store, wall, 40, "demo.bridge", "link lost"), wall * 10**9)
    logger.send_columns()
    texts = sorted((k for k in rec.rows if len(k) == 4), key=str)
    assert texts == [
        (SPINDLE, 0.0, "OK sensors: sensor spindle: ok (temperature_degc=25.0)", "INFO"),
        (SPINDLE, 2.0,
         "WARN sensors: sensor spindle: stale: no reading for 30 s (temperature_degc=25.0)", "WARN"),
        ("rosout/demo/bridge", None, "[demo.bridge] link lost", "ERROR")]    # before any data: no sim instant
    assert ("rosout/demo/bridge", float(wall), "[demo.bridge] link lost", "ERROR") in rec.walls
    assert not any(k[0].startswith(SPINDLE) for k in rec.walls)      # simulated-clock stamps stay on sim_time
    levels = sorted(k[1:] for k in rec.rows if k[0] == SPINDLE + "/level")
    assert levels == [(0.0, 0.0), (1.0, 0.0), (2.0, 1.0)]


@pytest.mark.parametrize("columnar", [False, True])
def test_wall_clock_records_sit_on_sim_time_where_they_arrived(columnar):
    """A log line or a wall-stamped status goes on sim_time at the newest data stamp before it
    (or the arrival given by the bag), its own stamp on wall_time only."""
    store = md.typestore()
    rec = _Capture()
    logger = RerunLogger(rec, columnar=columnar)
    for topic, type_name, t, msg in _synthetic_messages()[:8]:        # data up to t = 60 s
        logger.log(topic, type_name, msg, int(t * 1e9))
    wall = 1_795_808_975
    logger.log("/rosout", "rcl_interfaces/msg/Log", _log(store, wall, 20, "model", "fitted"), wall * 10**9)
    logger.log("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", _diagnostics(store, wall + 1, 0, "ok"),
               (wall + 1) * 10**9, arrival_ns=30 * 10**9)
    logger.send_columns()
    assert ("rosout/model", 60.0, "[model] fitted", "INFO") in rec.rows
    assert ("rosout/model", float(wall), "[model] fitted", "INFO") in rec.walls
    assert (SPINDLE + "/level", 30.0, 0.0) in rec.rows and (SPINDLE + "/level", wall + 1.0, 0.0) in rec.walls
    assert all(k[1] is None or k[1] <= 60.0 for k in rec.rows), sorted(rec.rows, key=str)


@pytest.mark.slow
@pytest.mark.ros
def test_live_view_shows_diagnostics_and_rosout(tmp_path, ros_context):
    import rclpy
    from thermal_comp_common.runtime.diagnostics import DiagnosticsPublisher
    out = tmp_path / "live.rrd"
    proc = subprocess.Popen([sys.executable, "-m", "thermal_comp.view.rerun_view_node", "--ros-args",
                             "-p", "spawn:=false", "-p", f"rrd:={out}"], env=_env(tmp_path),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    node = rclpy.create_node("health_source", context=ros_context)
    try:
        diag = DiagnosticsPublisher(node, hardware_id="test")
        wait_for(lambda: node.count_subscribers("/diagnostics") >= 1 or proc.poll() is not None, 30,
                 "the live viewer to subscribe to /diagnostics")
        assert proc.poll() is None, proc.communicate()[0]
        diag.set("link", "ERROR", "OPC UA link lost")
        wait_for(lambda: node.count_subscribers("/rosout") >= 1, 30, "the viewer on /rosout")
        node.get_logger().error("a line for the viewer")
        wait_for(lambda: out.exists() and {"/diagnostics/health_source/link", "/rosout/health_source"}
                 <= _entities(tmp_path, out), 30, "health in the .rrd", poll=0.5)
        out_text = stop(proc)
    finally:
        node.destroy_node()
    assert proc.returncode == 0, out_text


@pytest.mark.ros
def test_the_recorder_records_health_when_asked(tmp_path):
    import rclpy
    from thermal_comp.bags.recorder_node import BagRecorderNode
    topics = {}
    for health in (False, True):
        ctx = rclpy.context.Context()
        rclpy.init(args=["x", "--ros-args", "-p", f"output:={tmp_path / f'bag_{health}'}",
                         "-p", f"health:={str(health).lower()}"], context=ctx)
        node = BagRecorderNode(context=ctx)
        try:
            topics[health] = {topic for _, topic, _ in node._subs}
        finally:
            node.close()
            node.destroy_node()
            ctx.try_shutdown()
    assert topics[True] - topics[False] == {"/diagnostics", "/rosout"}
