"""Inspect a running graph: stand-ins for `ros2 topic list`, `ros2 topic echo`, `ros2 node list`.

Discovery takes a moment, so each command watches the graph for ``--wait`` seconds
(``--expect NAME`` returns as soon as every expected name is seen, or fails at the deadline).
``ROS_DOMAIN_ID`` selects the cell's domain (or ``--domain-id``).
"""
from __future__ import annotations

import argparse

from thermal_comp_common.command_line import run_parsed


def _common(ap: argparse.ArgumentParser, default_wait: float) -> None:
    ap.add_argument("--wait", type=float, default=default_wait,
                    help=f"seconds to watch the graph for discovery (default {default_wait})")
    ap.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID to inspect (default: the environment's)")


def topics_main(argv: list[str] | None = None) -> int:
    """List the topics of the graph with their types."""
    ap = argparse.ArgumentParser(prog="thermal-comp topics", description=topics_main.__doc__)
    _common(ap, 2.0)
    ap.add_argument("-t", "--show-types", action="store_true", help="print the type beside each topic")
    ap.add_argument("--expect", action="append", default=[], metavar="TOPIC",
                    help="return as soon as this topic is seen; fail if it is not seen in --wait s (repeatable)")
    args = ap.parse_args(argv)
    return run_parsed("thermal_comp.cell.inspect_graph:topics", args)


def nodes_main(argv: list[str] | None = None) -> int:
    """List the nodes of the graph (namespace/name)."""
    ap = argparse.ArgumentParser(prog="thermal-comp nodes", description=nodes_main.__doc__)
    _common(ap, 2.0)
    ap.add_argument("--expect", action="append", default=[], metavar="NODE",
                    help="return as soon as this node (/ns/name) is seen; fail if not (repeatable)")
    args = ap.parse_args(argv)
    return run_parsed("thermal_comp.cell.inspect_graph:nodes", args)


def echo_main(argv: list[str] | None = None) -> int:
    """Print the messages of a topic as YAML documents."""
    ap = argparse.ArgumentParser(prog="thermal-comp echo", description=echo_main.__doc__)
    _common(ap, 10.0)
    ap.add_argument("topic", help="topic name, e.g. /cell_a/temperatures")
    ap.add_argument("--type", help="message type (package/msg/Type); default: from the graph")
    ap.add_argument("-n", "--count", type=int, default=0, help="stop after N messages (default: run until Ctrl-C)")
    ap.add_argument("--once", action="store_true", help="same as --count 1")
    ap.add_argument("--reliable", action="store_true",
                    help="subscribe reliable (default best effort, which matches any publisher)")
    args = ap.parse_args(argv)
    return run_parsed("thermal_comp.cell.inspect_graph:echo", args)
