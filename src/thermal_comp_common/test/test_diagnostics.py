"""DiagnosticsPublisher: statuses reach /diagnostics at once on change and on the steady timer."""
from __future__ import annotations

import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor

from thermal_comp_common.runtime.diagnostics import (DIAGNOSTICS_QOS, TOPIC_DIAGNOSTICS,
                                             DiagnosticsPublisher, level_of)

pytestmark = [pytest.mark.ros]


def test_level_names_and_bytes():
    assert level_of("warn") == DiagnosticStatus.WARN
    assert level_of(2) == DiagnosticStatus.ERROR
    assert level_of(DiagnosticStatus.STALE) == DiagnosticStatus.STALE
    with pytest.raises(ValueError, match="'LOUD'"):
        level_of("LOUD")
    with pytest.raises(ValueError):
        level_of(7)


def _spin_until(executor, cond, deadline_s=10.0):
    end = time.monotonic() + deadline_s
    while time.monotonic() < end and not cond():
        executor.spin_once(timeout_sec=0.05)
    return cond()


def test_publishes_on_change_and_periodically(ros_context):
    node = rclpy.create_node("diag_under_test", context=ros_context)
    listener = rclpy.create_node("diag_listener", context=ros_context)
    got: list[DiagnosticArray] = []
    listener.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, got.append, DIAGNOSTICS_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(listener)
    try:
        diag = DiagnosticsPublisher(node, "cell0", period_s=0.2)
        assert _spin_until(ex, lambda: node.count_subscribers(TOPIC_DIAGNOSTICS) >= 1)
        diag.set("lock-step", "OK", "running", instant_s=0.0)
        assert _spin_until(ex, lambda: len(got) >= 1)
        st = got[0].status[0]
        assert st.name == "diag_under_test: lock-step"
        assert st.level == DiagnosticStatus.OK and st.message == "running"
        assert st.hardware_id == "cell0"
        assert {kv.key: kv.value for kv in st.values} == {"instant_s": "0.0"}
        # a change of level publishes at once, with every status
        diag.set("sensors", "WARN", "2 of 12 stale", stale=2)
        n = diag.published
        diag.set("sensors", "ERROR", "all stale", stale=12)
        assert diag.published == n + 1
        # the steady timer keeps publishing without any change
        before = len(got)
        assert _spin_until(ex, lambda: len(got) >= before + 3)
        last = {s.name: s for s in got[-1].status}
        assert last["diag_under_test: sensors"].level == DiagnosticStatus.ERROR
        assert diag.level("sensors") == DiagnosticStatus.ERROR and diag.level("x") is None
        # a value change alone does not publish at once (it travels with the next tick)
        n = diag.published
        diag.set("sensors", "ERROR", "all stale", stale=11)
        assert diag.published == n
    finally:
        ex.shutdown()
        node.destroy_node()
        listener.destroy_node()


def test_python_logging_reaches_rosout(ros_context):
    import logging

    from rcl_interfaces.msg import Log

    from thermal_comp_common.runtime.node_runtime import install_rosout_handler
    node = rclpy.create_node("logging_under_test", context=ros_context)
    listener = rclpy.create_node("rosout_listener", context=ros_context)
    got: list = []
    listener.create_subscription(Log, "/rosout", got.append, 100)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(listener)
    handler = install_rosout_handler(node)
    # other test modules quiet asyncua (setLevel at import): this test sets the levels it relies on
    saved = {name: logging.getLogger(name).level for name in ("asyncua", "asyncua.client")}
    for name in saved:
        logging.getLogger(name).setLevel(logging.NOTSET)
    try:
        assert _spin_until(ex, lambda: node.count_subscribers("/rosout") >= 1)
        logging.getLogger("asyncua.client").warning("link to %s lost", "opc.tcp://cnc:4840")
        logging.getLogger("pymodbus").debug("not forwarded below INFO")
        assert _spin_until(ex, lambda: any("link to" in m.msg for m in got))
        m = next(m for m in got if "link to" in m.msg)
        assert m.name == "logging_under_test" and m.level == Log.WARN
        assert m.msg == "[asyncua.client] link to opc.tcp://cnc:4840 lost"
        assert not any("not forwarded" in m.msg for m in got)
    finally:
        for name, level in saved.items():
            logging.getLogger(name).setLevel(level)
        logging.getLogger().removeHandler(handler)
        ex.shutdown()
        node.destroy_node()
        listener.destroy_node()


def test_library_info_records_stay_off_rosout():
    """asyncua logs every read and write at INFO: only our packages' INFO records go out."""
    import logging

    from thermal_comp_common.runtime.node_runtime import RosoutHandler

    sent: list = []

    class _Logger:
        def info(self, text):
            sent.append(text)

        warning = error = debug = info

    class _Node:
        def get_logger(self):
            return _Logger()

    h = RosoutHandler(_Node())
    for name, level in (("asyncua.client.ua_session", logging.INFO), ("asyncua.client", logging.WARNING),
                        ("thermal_sensors.modbus_source", logging.INFO)):
        h.handle(logging.LogRecord(name, level, __file__, 1, "m", None, None))
    assert sent == ["[asyncua.client] m", "[thermal_sensors.modbus_source] m"]


def test_an_unknown_executor_stops_the_node_in_one_line(monkeypatch, capsys):
    from thermal_comp_common.runtime.node_runtime import EXECUTOR_ENV, run_node
    monkeypatch.setenv(EXECUTOR_ENV, "fancy")
    assert run_node(lambda context: None, ["x"]) == 2
    assert capsys.readouterr().err.strip() == (f"environment {EXECUTOR_ENV}: 'fancy' is not one of "
                                               "['single', 'events']")
