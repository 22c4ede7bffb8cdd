"""The work of ``thermal-comp topics``, ``nodes``, ``echo`` and ``probe``
(:mod:`thermal_comp.cell.inspect_cli` parses the arguments), each through a
:class:`thermal_comp.api.Cell` attached to the domain."""
from __future__ import annotations

import math
import sys
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rich.console import Console
from rich.table import Table

from thermal_comp.api.cell import Cell, CellError
from thermal_comp.api.graph import MIN_WATCH_S, CellTimeout, type_class
from thermal_comp.api.results import ProbeResult
from thermal_comp_common.bags.message_text import message_to_yaml
from thermal_comp_common.plain_output import Progress, console, progress


def _listing(command: str, args, names_of) -> int:
    """Watch the graph, print the names ``names_of(snapshot)`` gives; exit 1 if an expected one is missing."""
    cell = Cell.attach("", args.domain_id)
    try:
        key = "expect_topics" if command == "topics" else "expect_nodes"
        # with expectations, return as soon as they are met; otherwise wait for the graph to settle
        snap = cell.watch_graph(args.wait, 0.0 if args.expect else args.settle,
                                include_hidden=args.include_hidden, min_s=0.0 if args.expect else MIN_WATCH_S,
                                **{key: args.expect})
    finally:
        cell.close()
    lines = names_of(snap)
    for line in lines:
        print(line)
    seen = {n for n, _ in snap.topics} if command == "topics" else set(snap.nodes)
    missing = set(args.expect) - seen
    how = (f"watched the graph {snap.waited_s:.1f} s (until the expected names were seen)"
           if args.expect and not missing else snap.describe(args.settle))
    print(f"thermal-comp {command}: {how}; {len(lines)} {command} (domain {cell.graph.domain_id})",
          file=sys.stderr)
    if missing:
        print(f"thermal-comp {command}: not seen within {args.wait:g} s: {', '.join(sorted(missing))}",
              file=sys.stderr)
        return 1
    return 0


def topics(args) -> int:
    """List the topics of the graph (exit 1: an expected one not seen)."""
    return _listing("topics", args, lambda s: [f"{n} [{', '.join(ts)}]" if args.show_types else n
                                                for n, ts in s.topics])


def nodes(args) -> int:
    """List the nodes of the graph (exit 1: an expected one not seen)."""
    return _listing("nodes", args, lambda s: list(s.nodes))


def echo(args) -> int:
    """Print the messages of a topic (exit 1: not seen, 2: unknown type)."""
    count = 1 if args.once else args.count
    cell = Cell.attach("", args.domain_id)
    received: list[Any] = []
    try:
        type_name = args.type
        if type_name is None:
            def typed():
                return dict(cell.graph.topics(include_hidden=True)).get(args.topic)
            if not cell.spin_until(lambda: typed() is not None, args.wait):
                print(f"thermal-comp echo: topic {args.topic} not seen within {args.wait:g} s "
                      f"(domain {cell.graph.domain_id})", file=sys.stderr)
                return 1
            type_name = typed()[0]
        try:
            cls = type_class(type_name)
        except ValueError as exc:
            print(f"thermal-comp echo: {exc}", file=sys.stderr)
            return 2
        qos = _echo_qos(cell, args.topic, args.reliable)

        def on_msg(msg):
            received.append(msg)
            print(message_to_yaml(msg) + "---", flush=True)

        cell.subscribe(args.topic, cls, on_msg, qos)
        limit = count if count > 0 else math.inf
        try:  # until the count or Ctrl-C: the user asked for a stream
            cell.spin_until(lambda: len(received) >= limit or not cell.graph.ctx.ok(), math.inf)
        except KeyboardInterrupt:
            pass
    finally:
        cell.close()
    return 0


def _echo_qos(cell: Cell, topic: str, reliable: bool) -> QoSProfile:
    """Best effort and volatile match any publisher; like ``ros2 topic echo``, take reliable and
    transient local where every publisher offers them, so a latched message (``/tf_static``, the
    model's status) arrives at once."""
    pubs = cell.node.get_publishers_info_by_topic(topic)
    offered = [p.qos_profile for p in pubs]
    all_reliable = bool(offered) and all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    all_latched = bool(offered) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE if (reliable or all_reliable) else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if all_latched else DurabilityPolicy.VOLATILE)


def probe(args, angles: list[float]) -> int:
    """Run the cycle the parsed arguments ask for; the exit code (0 succeeded, 1 failed or
    refused, 2 no server answered)."""
    out = console()
    cell = Cell.attach(args.namespace, args.domain_id)
    bar: list[Progress] = []

    def on_feedback(fb) -> None:   # a bar on a terminal, a plain line per tenth in a log file
        if not bar and fb.points_total > 0:
            bar.append(progress(fb.points_total, "probing", "points"))
        if bar:
            bar[0].to(fb.points_done)

    try:
        result = cell.probe(guide_bush=args.guide_bush, set_reference=args.set_reference,
                            points=args.points, angles=angles, cycle_timeout_s=args.timeout,
                            server_wait_s=args.wait, deadline_s=args.deadline,
                            busy_retry_s=args.busy_retry, on_feedback=on_feedback)
        if result.success and bar:
            # result and feedback travel on separate topics, the result may overtake the last
            # feedback: a cycle that succeeded probed every point
            bar[0].to(bar[0].total)
    except CellTimeout as exc:
        print(f"thermal-comp probe: {exc} (namespace '{args.namespace or '/'}', domain "
              f"{cell.graph.domain_id})", file=sys.stderr)
        return 2 if "action server" in str(exc) else 1
    except CellError as exc:
        print(f"thermal-comp probe: {exc}", file=sys.stderr)
        return 1
    finally:
        if bar:
            bar[0].close()
        cell.close()
    if not result.success:
        out.print(f"[red]probe cycle failed:[/red] {result.message}")
        return 1
    _print_result(out, result)
    return 0


def _print_result(console: Console, result: ProbeResult) -> None:
    e = result.errors
    table = Table(title=f"{e.model_kind}: {result.message.split(':')[0]}")
    for col in ("component", "value", "U (k=2)", "unit"):
        table.add_column(col, justify="left" if col in ("component", "unit") else "right")
    for name, v in e.values.items():
        table.add_row(name, f"{v:+.2f}", f"{2 * e.uncertainties[name]:.2f}", e.units[name])
    console.print(table)
    console.print(f"duration {result.duration_s:.1f} s, fit RMS {result.fit_residual_rms_um:.2f} um, "
                  f"360/0 check {result.repeatability_check_um:.2f} um")

