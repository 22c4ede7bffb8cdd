"""Inspect and drive a running graph: stand-ins for `ros2 topic list`, `ros2 topic echo`, `ros2 node list`, a probing cycle.

Discovery takes a moment: ``topics`` and ``nodes`` watch the graph for at least one DDS
announcement period (3.5 s) and until it has not changed for ``--settle`` seconds (at most
``--wait``), and say on stderr how long they watched;
``--expect NAME`` returns as soon as every expected name is seen, or fails at the deadline.
``/rosout``, ``/parameter_events`` and hidden names (the command line's own helper nodes, an
action's ``_action`` topics) are left out unless ``--all``. ``ROS_DOMAIN_ID`` selects the
cell's domain (or ``--domain-id``). All of them go through :class:`thermal_comp.api.Cell`.
"""
from __future__ import annotations

import argparse
import math
import sys

from probe_cycle.probe_cli import build_parser as probe_parser
from thermal_comp_common.command_line import run_parsed


def _common(ap: argparse.ArgumentParser, default_wait: float) -> None:
    ap.add_argument("--wait", type=float, default=default_wait,
                    help=f"most seconds to watch the graph for discovery (default {default_wait:g})")
    ap.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID to inspect (default: the environment's)")


def _listing(ap: argparse.ArgumentParser, what: str) -> None:
    _common(ap, 10.0)
    ap.add_argument("--settle", type=float, default=1.5,
                    help="seconds without change after which the graph counts as discovered (default 1.5)")
    ap.add_argument("-a", "--all", action="store_true", dest="include_hidden",
                    help=f"also list {what}")


def _check_waits(ap: argparse.ArgumentParser, args) -> None:
    for name in ("wait", "settle"):
        v = getattr(args, name, 0.0)
        if not (math.isfinite(v) and v >= 0):
            ap.error(f"--{name}: {v} is not a finite number of seconds >= 0")


def topics_main(argv: list[str] | None = None) -> int:
    """List the topics of the graph with their types."""
    ap = argparse.ArgumentParser(prog="thermal-comp topics", description=topics_main.__doc__)
    _listing(ap, "/rosout, /parameter_events and hidden topics (e.g. an action's _action/*)")
    ap.add_argument("-t", "--show-types", action="store_true", help="print the type beside each topic")
    ap.add_argument("--expect", action="append", default=[], metavar="TOPIC",
                    help="return as soon as this topic is seen; fail if it is not seen in --wait s (repeatable)")
    args = ap.parse_args(argv)
    _check_waits(ap, args)
    return run_parsed("thermal_comp.cell.inspect_graph:topics", args)


def nodes_main(argv: list[str] | None = None) -> int:
    """List the nodes of the graph (namespace/name)."""
    ap = argparse.ArgumentParser(prog="thermal-comp nodes", description=nodes_main.__doc__)
    _listing(ap, "hidden nodes (names starting with '_', e.g. this command's own helper node)")
    ap.add_argument("--expect", action="append", default=[], metavar="NODE",
                    help="return as soon as this node (/ns/name) is seen; fail if not (repeatable)")
    args = ap.parse_args(argv)
    _check_waits(ap, args)
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
                    help="subscribe reliable (default: reliable and transient local only where every "
                         "publisher offers them, else best effort and volatile, which match any publisher)")
    args = ap.parse_args(argv)
    _check_waits(ap, args)
    return run_parsed("thermal_comp.cell.inspect_graph:echo", args)


def _angles(text: str) -> list[float]:
    """``--angles`` "0,90,180" -> floats (ValueError naming the bad item)."""
    out = []
    for item in filter(None, (t.strip() for t in text.split(","))):
        try:
            v = float(item)
        except ValueError:
            raise ValueError(f"--angles: '{item}' is not a number") from None
        if not math.isfinite(v):
            raise ValueError(f"--angles: '{item}' is not finite")
        out.append(v)
    return out


def probe_main(argv: list[str] | None = None) -> int:
    """Run one probing cycle on a running probe_cycle server and print the measured errors."""
    ap = probe_parser()
    ap.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID of the cell (default: the environment's)")
    ap.add_argument("--busy-retry", type=float, default=0.0,
                    help="seconds to keep re-sending a goal the server refuses because a cycle runs (default 0)")
    args = ap.parse_args(argv)
    try:
        angles = _angles(args.angles)
    except ValueError as exc:
        print(f"thermal-comp probe: {exc}", file=sys.stderr)
        return 2
    if args.points < 0:
        print(f"thermal-comp probe: --points: {args.points} is negative", file=sys.stderr)
        return 2
    return run_parsed("thermal_comp.cell.inspect_graph:probe", args, angles)
