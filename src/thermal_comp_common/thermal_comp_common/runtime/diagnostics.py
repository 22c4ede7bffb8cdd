"""Health you can see: one ``/diagnostics`` publisher per node (diagnostic_msgs/DiagnosticArray).

A node keeps a few named statuses (``link``, ``lock-step``, ``sensors`` ...) and sets them
as things happen; :class:`DiagnosticsPublisher` sends all of them on ``/diagnostics`` once a
second on a steady (wall) timer -- so a node whose simulated clock stands still still says
so -- and at once when a status's level or message changes. Values are key/value strings
(numbers formatted with ``repr``) and travel with the next publication.

Status names are ``"<node name>: <name>"`` as the ROS diagnostics tools expect; the
hardware id names the machine or device the node talks to (the cell, the CNC, the sensors).

This module imports rclpy (it is part of the ROS shell, like :mod:`node_runtime`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: The standard, absolute topic (one for the whole graph, whatever the node's namespace).
TOPIC_DIAGNOSTICS = "/diagnostics"
#: Seconds between two periodic publications.
PERIOD_S = 1.0

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE
#: Level names accepted by :meth:`DiagnosticsPublisher.set` besides the byte constants.
LEVELS = {"OK": OK, "WARN": WARN, "ERROR": ERROR, "STALE": STALE}
LEVEL_NAMES = {v: k for k, v in LEVELS.items()}

DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)


def level_of(level: Any) -> bytes:
    """``"WARN"``, ``1``, ``b"\\x01"`` or ``DiagnosticStatus.WARN`` -> the byte level."""
    if isinstance(level, str):
        try:
            return LEVELS[level.upper()]
        except KeyError:
            raise ValueError(f"diagnostic level {level!r} is not one of {list(LEVELS)}") from None
    if isinstance(level, int) and not isinstance(level, bool):
        level = bytes([level])
    if level not in LEVEL_NAMES:
        raise ValueError(f"diagnostic level {level!r} is not one of {list(LEVELS)}")
    return level


def _text(v: Any) -> str:
    return v if isinstance(v, str) else repr(v)


@dataclass
class _Status:
    level: bytes
    message: str
    values: dict[str, str] = field(default_factory=dict)


class DiagnosticsPublisher:
    """Publish a node's named statuses on ``/diagnostics`` (1 Hz and on change).

    >>> diag = DiagnosticsPublisher(node, hardware_id="cell0")
    >>> diag.set("lock-step", "WARN", "waiting for talc_model", instant_s=3600.0)
    """

    def __init__(self, node, hardware_id: str, period_s: float = PERIOD_S):
        self._node = node
        self._hardware_id = str(hardware_id)
        self._statuses: dict[str, _Status] = {}
        self._pub = node.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, DIAGNOSTICS_QOS)
        self.published = 0
        # steady clock: a node whose simulated time stands still must still report
        self._timer = node.create_timer(period_s, self.publish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def set(self, name: str, level: Any, message: str, **values: Any) -> None:
        """Set status ``name``; publish at once when its level or message changed."""
        lv = level_of(level)
        old = self._statuses.get(name)
        self._statuses[name] = _Status(lv, str(message), {k: _text(v) for k, v in values.items()})
        if old is None or old.level != lv or old.message != str(message):
            self.publish()

    def update_values(self, name: str, **values: Any) -> None:
        """Change values of status ``name`` (sent with the next periodic publication)."""
        s = self._statuses.get(name)
        if s is not None:
            s.values.update({k: _text(v) for k, v in values.items()})

    def level(self, name: str) -> bytes | None:
        """The current level of ``name`` (None when never set)."""
        s = self._statuses.get(name)
        return None if s is None else s.level

    def statuses(self) -> list[DiagnosticStatus]:
        """The current statuses as messages, in the order they were first set."""
        prefix = self._node.get_name()
        return [DiagnosticStatus(level=s.level, name=f"{prefix}: {name}", message=s.message,
                                 hardware_id=self._hardware_id,
                                 values=[KeyValue(key=k, value=v) for k, v in s.values.items()])
                for name, s in self._statuses.items()]

    def publish(self) -> None:
        """Send every status now (nothing when no status was set yet)."""
        if not self._statuses:
            return
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.status = self.statuses()
        self._pub.publish(msg)
        self.published += 1

    def destroy(self) -> None:
        """Stop the timer and the publisher (the node's own destroy does it too)."""
        self._node.destroy_timer(self._timer)
        self._node.destroy_publisher(self._pub)
