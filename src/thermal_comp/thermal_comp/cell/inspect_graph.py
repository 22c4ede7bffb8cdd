"""The work of ``thermal-comp topics``, ``nodes`` and ``echo`` (:mod:`thermal_comp.cell.inspect_cli` parses
the arguments): an rclpy node that watches the graph of a domain for discovery's time."""
from __future__ import annotations

import importlib
import math
import os
import sys
import time
from typing import Any, Iterable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from thermal_comp_common.bags.message_text import message_to_yaml


def _type_class(type_name: str):
    """'pkg/msg/Type' -> the Python message class."""
    parts = type_name.split("/")
    if len(parts) != 3:
        raise ValueError(f"type {type_name!r} is not of the form package/msg/Type")
    pkg, kind, name = parts
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {type_name!r} is not installed in this environment") from None


class GraphWatcher:
    """An rclpy node in its own context that watches the graph (topics, nodes) of a domain."""

    def __init__(self, domain_id: int | None):
        if domain_id is not None:
            os.environ["ROS_DOMAIN_ID"] = str(domain_id)
        self.ctx = rclpy.context.Context()
        rclpy.init(args=[], context=self.ctx)
        self.node = rclpy.create_node(f"thermal_comp_inspect_{os.getpid()}", context=self.ctx,
                                      start_parameter_services=False, enable_rosout=False)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)

    def spin_until(self, done, wait_s: float) -> bool:
        """Spin until done() is true or wait_s elapsed (wall time: discovery is a wall-time process)."""
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            if done():
                return True
            self.executor.spin_once(timeout_sec=0.1)
        return bool(done())

    def topics(self) -> list[tuple[str, list[str]]]:
        own = {"/parameter_events", "/rosout"}
        return [(n, t) for n, t in self.node.get_topic_names_and_types() if n not in own]

    def nodes(self) -> list[str]:
        me = self.node.get_name()
        out = []
        for name, ns in self.node.get_node_names_and_namespaces():
            if name == me:
                continue
            out.append((ns.rstrip("/") + "/" + name) if ns != "/" else "/" + name)
        return sorted(set(out))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        if self.ctx.ok():
            self.ctx.try_shutdown()


def _watch_names(get, expect: Iterable[str], wait_s: float, w: GraphWatcher) -> tuple[list, set]:
    expect = set(expect)
    if expect:
        w.spin_until(lambda: expect <= {x if isinstance(x, str) else x[0] for x in get()}, wait_s)
    else:  # no expectation: watch the whole time, the list only grows during discovery
        w.spin_until(lambda: False, wait_s)
    found = get()
    missing = expect - {x if isinstance(x, str) else x[0] for x in found}
    return found, missing


def _report(command: str, lines: list[str], missing: set, wait_s: float) -> int:
    """Print what was found; name what was expected but not seen (exit 1)."""
    for line in lines:
        print(line)
    if missing:
        print(f"thermal-comp {command}: not seen within {wait_s:g} s: {', '.join(sorted(missing))}", file=sys.stderr)
        return 1
    return 0


def topics(args) -> int:
    """List the topics of the graph (exit 1: an expected one not seen)."""
    w = GraphWatcher(args.domain_id)
    try:
        found, missing = _watch_names(w.topics, args.expect, args.wait, w)
    finally:
        w.close()
    return _report("topics", [f"{n} [{', '.join(ts)}]" if args.show_types else n for n, ts in sorted(found)],
                   missing, args.wait)


def nodes(args) -> int:
    """List the nodes of the graph (exit 1: an expected one not seen)."""
    w = GraphWatcher(args.domain_id)
    try:
        found, missing = _watch_names(w.nodes, args.expect, args.wait, w)
    finally:
        w.close()
    return _report("nodes", found, missing, args.wait)


def echo(args) -> int:
    """Print the messages of a topic (exit 1: not seen, 2: unknown type)."""
    count = 1 if args.once else args.count
    w = GraphWatcher(args.domain_id)
    received: list[Any] = []
    try:
        type_name = args.type
        if type_name is None:
            def typed():
                return dict(w.topics()).get(args.topic)
            if not w.spin_until(lambda: typed() is not None, args.wait):
                print(f"thermal-comp echo: topic {args.topic} not seen within {args.wait:g} s "
                      f"(domain {os.environ.get('ROS_DOMAIN_ID', '0')})", file=sys.stderr)
                return 1
            type_name = typed()[0]
        try:
            cls = _type_class(type_name)
        except ValueError as exc:
            print(f"thermal-comp echo: {exc}", file=sys.stderr)
            return 2
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                         reliability=ReliabilityPolicy.RELIABLE if args.reliable else ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)

        def on_msg(msg):
            received.append(msg)
            print(message_to_yaml(msg) + "---", flush=True)

        w.node.create_subscription(cls, args.topic, on_msg, qos)
        limit = count if count > 0 else math.inf
        try:
            while w.ctx.ok() and len(received) < limit:
                w.executor.spin_once(timeout_sec=0.2)
        except KeyboardInterrupt:
            pass
    finally:
        w.close()
    return 0
