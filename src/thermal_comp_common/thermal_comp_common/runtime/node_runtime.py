"""Conventions every thermal-comp node follows (the thin ROS shell around a pure core).

- Parameters are declared with a description and, for numbers, a validated range
  (:func:`declare_parameters`); a bad value stops the node with one line naming it.
- ``main()`` of a node file is ``run_node(MyNode, args)``: an own rclpy context, a
  single-threaded executor (or multi-threaded on request), SIGINT/SIGTERM and
  ExternalShutdownException handled, the node destroyed and the context shut down.
- Simulated time: every node accepts ``use_sim_time`` (rclpy declares it); nodes stamp
  messages with ``node.get_clock().now()``, never with the wall clock.
- QoS profiles are the named ones below, chosen per kind of data.

This module imports rclpy; pure cores must not import it.
"""
from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

from builtin_interfaces.msg import Time
import rclpy
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.signals import SignalHandlerOptions
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

# --------------------------------------------------------------------------------------
# QoS, chosen per kind of data (documented in docs/architecture.md).
#: Temperature and machine-state streams: reliable, keep the last 50. Reliable because a
#: model that misses samples in lock-step simulation would not be deterministic, and the
#: rate (<= 10 Hz) makes reliability cheap; depth 50 absorbs a slow subscriber for a while.
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: Predictions, offsets, measured errors: reliable, deep history (nothing may be lost).
EVENT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
#: Latest-state topics a late joiner needs at once (model status, configuration):
#: reliable, transient local, depth 1.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Monitoring-only streams where the newest value matters (viewer feeds): best effort.
MONITOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)

# --------------------------------------------------------------------------------------
# Topic and service names, relative so that a cell's namespace applies.
TOPIC_TEMPERATURES = "temperatures"               # TemperatureArray, calibrated, with status
TOPIC_TWIN_SENSORS = "twin/sensor_readings"       # TemperatureArray, raw readings of the twin
TOPIC_MACHINE_STATE = "machine_state"             # MachineState
TOPIC_ERRORS_TRUE = "errors/ground_truth"         # ThermalErrors (twin only, evaluation)
TOPIC_ERRORS_PREDICTED = "errors/predicted"       # ThermalErrors from the model
TOPIC_ERRORS_MEASURED = "errors/measured"         # ThermalErrors from successful probing
TOPIC_OFFSETS = "offsets"                         # AxisOffsets from the CNC bridge
TOPIC_MODEL_STATUS = "model_status"               # ModelStatus
TOPIC_SIM_SYNC = "sim_sync"                       # SimSync lock-step handshake
SERVICE_TOUCH_PROBE = "twin/touch_probe"          # TouchProbe
ACTION_PROBE_CYCLE = "probe_cycle"                # ProbeCycle


class ParameterError(ValueError):
    """A node parameter has a value outside its declared range or type."""


@dataclass(frozen=True)
class Param:
    """Declaration of one node parameter.

    ``lo``/``hi`` bound numbers (inclusive); ``choices`` bounds strings.
    """

    name: str
    default: Any
    description: str
    lo: float | None = None
    hi: float | None = None
    choices: Sequence[str] | None = None
    read_only: bool = False
    dynamic_typing: bool = False


def _descriptor(p: Param) -> ParameterDescriptor:
    desc = p.description
    if p.choices:
        desc += f" (one of: {', '.join(p.choices)})"
    d = ParameterDescriptor(description=desc, read_only=p.read_only,
                            dynamic_typing=p.dynamic_typing)
    if isinstance(p.default, bool):
        return d
    if isinstance(p.default, int) and (p.lo is not None or p.hi is not None):
        d.integer_range = [IntegerRange(from_value=int(p.lo if p.lo is not None else -2**62),
                                        to_value=int(p.hi if p.hi is not None else 2**62), step=0)]
    elif isinstance(p.default, float) and (p.lo is not None or p.hi is not None):
        d.floating_point_range = [FloatingPointRange(
            from_value=float(p.lo if p.lo is not None else -sys.float_info.max),
            to_value=float(p.hi if p.hi is not None else sys.float_info.max), step=0.0)]
    return d


def check_value(p: Param, value: Any) -> None:
    """Raise :class:`ParameterError` naming the parameter if ``value`` is not allowed."""
    if isinstance(value, float) and math.isnan(value):
        raise ParameterError(f"parameter '{p.name}': NaN is not allowed")
    if p.lo is not None and isinstance(value, (int, float)) and not isinstance(value, bool) \
            and value < p.lo:
        raise ParameterError(f"parameter '{p.name}': {value!r} is below the minimum {p.lo}")
    if p.hi is not None and isinstance(value, (int, float)) and not isinstance(value, bool) \
            and value > p.hi:
        raise ParameterError(f"parameter '{p.name}': {value!r} is above the maximum {p.hi}")
    if p.choices is not None and value not in p.choices:
        raise ParameterError(f"parameter '{p.name}': {value!r} is not one of {list(p.choices)}")


def declare_parameters(node: Node, params: Iterable[Param]) -> dict[str, Any]:
    """Declare ``params`` on ``node`` with descriptors, validate them and return the values.

    Later changes through the parameter service are validated the same way.
    """
    table = {p.name: p for p in params}
    values: dict[str, Any] = {}
    for p in table.values():
        node.declare_parameter(p.name, p.default, _descriptor(p))
        v = node.get_parameter(p.name).value
        check_value(p, v)
        values[p.name] = v

    def _on_set(changes) -> SetParametersResult:
        for c in changes:
            if c.name in table:
                try:
                    check_value(table[c.name], c.value)
                except ParameterError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(_on_set)
    return values


def stamp_to_s(stamp) -> float:
    """builtin_interfaces/Time -> seconds (float)."""
    return stamp.sec + stamp.nanosec * 1e-9


def s_to_stamp(t_s: float):
    """Seconds -> builtin_interfaces/Time (rounded to the nanosecond)."""
    ns = int(round(t_s * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


#: Top-level packages whose INFO records are forwarded; other libraries' (asyncua logs every
#: read and write at INFO: one /rosout message per instant and per node) from ``library_level``.
OWN_PACKAGES = ("thermal_comp", "thermal_comp_common", "thermal_twin", "thermal_sensors",
                "thermal_eval", "talc_model", "probe_cycle", "cnc_bridge", "__main__")


class RosoutHandler(logging.Handler):
    """Forward Python ``logging`` records (backends: OPC UA, Modbus, models) to a node's rclpy
    logger, so they reach ``/rosout`` and the viewer: ours from ``level``, other libraries'
    from ``library_level``. :func:`run_node` installs one on the root logger for the node's
    lifetime."""

    def __init__(self, node: Node, level: int = logging.INFO, library_level: int = logging.WARNING):
        super().__init__(level)
        self._logger = node.get_logger()
        self.library_level = library_level

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno < self.library_level and record.name.split(".", 1)[0] not in OWN_PACKAGES:
            return
        try:
            text = f"[{record.name}] {self.format(record)}"
            if record.levelno >= logging.ERROR:
                self._logger.error(text)
            elif record.levelno >= logging.WARNING:
                self._logger.warning(text)
            elif record.levelno >= logging.INFO:
                self._logger.info(text)
            else:
                self._logger.debug(text)
        except Exception:   # logging must never take the node down
            self.handleError(record)


def install_rosout_handler(node: Node, level: int = logging.INFO) -> RosoutHandler:
    """Attach a :class:`RosoutHandler` to the root logger (and let INFO records through)."""
    handler = RosoutHandler(node, level)
    root = logging.getLogger()
    root.addHandler(handler)
    if root.level > level or root.level == logging.NOTSET:
        root.setLevel(level)
    return handler


#: After a stop signal a node with ``drain_activity`` keeps spinning while its counter still
#: moves: until it stood still this long (s) ...
DRAIN_QUIET_S = 0.3
#: ... but no longer than this (s).
DRAIN_MAX_S = 3.0


def _drain(executor, node, context) -> None:
    """Take what already arrived before closing: a recorder stopped right after the last instant
    still has that instant's messages in its subscription queues. ``node.drain_activity()``
    returns a counter (messages written); spin until it has not moved for ``DRAIN_QUIET_S``,
    at most ``DRAIN_MAX_S``. Nodes without it stop at once."""
    activity = getattr(node, "drain_activity", None)
    if not callable(activity):
        return
    start = last_change = time.monotonic()
    seen = activity()
    while context.ok() and time.monotonic() - start < DRAIN_MAX_S:
        executor.spin_once(timeout_sec=0.05)
        now_seen = activity()
        if now_seen != seen:
            seen, last_change = now_seen, time.monotonic()
        elif time.monotonic() - last_change >= DRAIN_QUIET_S:
            return


#: Environment variable choosing the executor of single-threaded nodes: ``single`` (rclpy's
#: SingleThreadedExecutor, the default) or ``events`` (rclpy's experimental EventsExecutor, C++
#: event queue: about a third of the CPU per message, measured by a ping-pong between two
#: processes; ``bench graph`` reports the graph with either).
EXECUTOR_ENV = "THERMAL_COMP_EXECUTOR"
EXECUTOR_KINDS = ("single", "events")


def make_executor(context, kind: str | None = None, multi_threaded: bool = False, num_threads: int = 2):
    """The executor of a node: multi-threaded on request, else ``kind`` (single or events;
    None: the environment's :data:`EXECUTOR_ENV`, default single)."""
    kind = kind or os.environ.get(EXECUTOR_ENV, "single")
    if kind not in EXECUTOR_KINDS:
        raise ValueError(f"environment {EXECUTOR_ENV}: {kind!r} is not one of {list(EXECUTOR_KINDS)}")
    if multi_threaded:
        return MultiThreadedExecutor(num_threads=num_threads, context=context)
    if kind == "events":
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def run_node(node_factory: Callable[..., Node], args: list[str] | None = None,
             multi_threaded: bool = False, num_threads: int = 2, poll_s: float = 0.1) -> int:
    """Run one node in its own context until SIGINT, SIGTERM or an external shutdown.

    ``node_factory(context=ctx)`` builds the node. rclpy's own signal handlers are not
    installed; SIGINT and SIGTERM set a flag that the spin loop checks every ``poll_s``
    (a blocking ``spin()`` would not return on a signal with the multi-threaded executor).
    Returns a process exit code: 0 on a clean shutdown, 2 when the node's parameters are
    invalid (message printed, naming the parameter), 1 when the node's own cleanup failed,
    or the node's own ``exit_code`` attribute when it is set (a node that stopped itself on a
    fault it reported, e.g. machine_sim's lock-step deadline: 3).
    """
    if args is None:
        args = sys.argv
    kind = os.environ.get(EXECUTOR_ENV, "single")
    if kind not in EXECUTOR_KINDS:
        print(f"environment {EXECUTOR_ENV}: {kind!r} is not one of {list(EXECUTOR_KINDS)}",
              file=sys.stderr, flush=True)
        return 2
    context = rclpy.context.Context()
    rclpy.init(args=args, context=context, signal_handler_options=SignalHandlerOptions.NO)
    executor = make_executor(context, kind, multi_threaded, num_threads)
    stop = threading.Event()

    def _on_signal(signum, frame):
        stop.set()

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    node = None
    handler = None
    code = 0
    try:
        try:
            node = node_factory(context=context)
        except (ParameterError, ValueError, InvalidParameterValueException, ParameterException) as exc:
            # one line naming the parameter; rclpy's own range check raises its exceptions
            print(f"{getattr(node_factory, '__name__', 'node')}: {exc}", file=sys.stderr, flush=True)
            return 2
        handler = install_rosout_handler(node)
        executor.add_node(node)
        while context.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=poll_s)
        _drain(executor, node, context)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if handler is not None:
            logging.getLogger().removeHandler(handler)
        if node is not None:
            close = getattr(node, "close", None)
            if callable(close):
                try:
                    close()
                except Exception as exc:  # the node's own cleanup must not hide the shutdown
                    print(f"error while closing node: {exc}", file=sys.stderr, flush=True)
                    code = 1
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        if context.ok():
            context.try_shutdown()
    return code or int(getattr(node, "exit_code", 0) or 0)
