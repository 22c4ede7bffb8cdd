"""A view of a ROS graph from a hidden node of its own: topics, nodes, and how long discovery took.

The node lives in its own rclpy context (a script, a notebook or a test can hold several, on
different domains) and is named with a leading underscore, the ROS convention for a hidden
node, so ``thermal-comp nodes`` and ``ros2 node list`` leave it (and the other helpers of the
command line) out. Every wait is bounded: a deadline in wall time, since discovery is a
wall-time process whatever clock the cell runs on.
"""
from __future__ import annotations

import importlib
import itertools
import os
import time
from dataclasses import dataclass
from typing import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor

#: topics every node has (``ros2 topic list`` shows them; here they need ``include_hidden``)
INFRASTRUCTURE_TOPICS = ("/parameter_events", "/rosout")
#: Fast DDS re-announces a participant every 3 s after its initial burst: one that missed the
#: burst (a loaded machine) is only seen at the next announcement, so an unchanged graph means
#: little before one period (plus margin) has passed
ANNOUNCEMENT_PERIOD_S = 3.0
MIN_WATCH_S = ANNOUNCEMENT_PERIOD_S + 0.5
_counter = itertools.count()


class CellTimeout(TimeoutError):
    """A bounded wait ran out; the message says what was waited for and how long."""


@dataclass(frozen=True)
class GraphSnapshot:
    """What discovery showed: names, how long it was watched, and whether it had settled."""
    topics: list[tuple[str, list[str]]]
    nodes: list[str]
    waited_s: float
    stable: bool            # nothing changed for the settle time before the watch ended

    def describe(self, settle_s: float) -> str:
        how = (f"graph stable for {settle_s:g} s" if self.stable
               else "graph still changing at the deadline")
        return f"watched the graph {self.waited_s:.1f} s ({how})"


def is_hidden(name: str) -> bool:
    """A hidden node or topic (ROS convention): a segment of its name starts with an underscore,
    e.g. a helper node ``_thermal_comp_cli_...`` or an action's ``/probe_cycle/_action/status``."""
    return any(part.startswith("_") for part in name.split("/"))


def type_class(type_name: str):
    """'pkg/msg/Type' -> the Python message class (ValueError naming the type if unknown)."""
    parts = type_name.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"type {type_name!r} is not of the form package/msg/Type")
    pkg, kind, name = parts
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {type_name!r} is not installed in this environment") from None


class SettleRule:
    """When a watched graph counts as discovered: at least ``min_s`` after ``start``, nothing
    changed for ``settle_s``, and every expected topic and node seen (times in seconds)."""

    def __init__(self, start: float, settle_s: float, min_s: float, expect_topics=frozenset(),
                 expect_nodes=frozenset()):
        self.start, self.settle_s, self.min_s = start, settle_s, min_s
        self.expect_topics, self.expect_nodes = set(expect_topics), set(expect_nodes)
        self.last: tuple | None = None
        self.since = start

    def settled(self, topics: set[str], nodes: set[str], now: float) -> bool:
        seen = (frozenset(topics), frozenset(nodes))
        if seen != self.last:
            self.last, self.since = seen, now
        if not (self.expect_topics <= topics and self.expect_nodes <= nodes):
            return False
        return now - self.since >= self.settle_s and now - self.start >= self.min_s


class GraphView:
    """A hidden rclpy node in its own context on ``domain_id`` (None: the environment's)."""

    def __init__(self, domain_id: int | None = None, namespace: str = "", role: str = "api"):
        if domain_id is not None and not (isinstance(domain_id, int) and 0 <= domain_id <= 232):
            raise ValueError(f"domain_id: {domain_id!r} is not a ROS domain id (0-232)")
        self.domain_id = domain_id if domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
        self.ctx = rclpy.context.Context()
        rclpy.init(args=[], context=self.ctx, domain_id=self.domain_id)
        self.node = rclpy.create_node(f"_thermal_comp_{role}_{os.getpid()}_{next(_counter)}",
                                      namespace=namespace or None, context=self.ctx,
                                      start_parameter_services=False, enable_rosout=False)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)

    def spin_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until ``done()`` is true or ``timeout_s`` (wall time) passed; whether it came true."""
        deadline = time.monotonic() + max(0.0, float(timeout_s))
        while True:
            if done():
                return True
            left = deadline - time.monotonic()
            if left <= 0 or not self.ctx.ok():
                return bool(done())
            self.executor.spin_once(timeout_sec=min(0.1, left))

    def topics(self, include_hidden: bool = False) -> list[tuple[str, list[str]]]:
        """(name, types) of every topic, sorted; /rosout, /parameter_events and hidden ones
        only with ``include_hidden``."""
        out = []
        for name, types in self.node.get_topic_names_and_types():
            if not include_hidden and (name in INFRASTRUCTURE_TOPICS or is_hidden(name)):
                continue
            out.append((name, list(types)))
        return sorted(out)

    def nodes(self, include_hidden: bool = False) -> list[str]:
        """Full names (/ns/name) of the nodes, sorted; hidden ones (this one, the command
        line's helpers) only with ``include_hidden``."""
        out = set()
        for name, ns in self.node.get_node_names_and_namespaces():
            full = (ns.rstrip("/") + "/" + name) if ns != "/" else "/" + name
            if include_hidden or not is_hidden(name):
                out.add(full)
        return sorted(out)

    def watch(self, max_wait_s: float, settle_s: float = 1.5, expect_topics=(), expect_nodes=(),
              include_hidden: bool = False, min_s: float = MIN_WATCH_S) -> GraphSnapshot:
        """Watch discovery until at least ``min_s`` passed, the graph has not changed for
        ``settle_s`` and every expected name is seen, or ``max_wait_s`` passed; the snapshot says
        which and how long it took."""
        start = time.monotonic()
        rule = SettleRule(start, settle_s, min_s, set(expect_topics), set(expect_nodes))

        def settled() -> bool:
            names = ({n for n, _ in self.topics(include_hidden)}, set(self.nodes(include_hidden)))
            return rule.settled(names[0], names[1], time.monotonic())

        stable = self.spin_until(settled, max_wait_s)
        return GraphSnapshot(self.topics(include_hidden), self.nodes(include_hidden),
                             time.monotonic() - start, stable)

    def close(self) -> None:
        """Destroy the node and shut its context down (idempotent)."""
        if getattr(self, "_closed", False):
            return
        self._closed = True
        self.executor.shutdown()
        self.node.destroy_node()
        if self.ctx.ok():
            self.ctx.try_shutdown()
