"""The work of ``thermal-comp view`` (:mod:`thermal_comp.view.cli` parses the arguments): a bag or
the live topics into rerun; and :func:`bag_to_rrd`, a whole bag into an .rrd file (also the demo's).
"""
from __future__ import annotations

import pathlib
import signal
import sys
import threading

import numpy as np
import rerun as rr

from thermal_comp.view.blueprint import default_blueprint
from thermal_comp.view.rerun_logging import FOREIGN_TYPES, LayoutError, RerunLogger, resolve_layout, split_topic
from thermal_comp.view.rerun_sinks import FLUSH_TIMEOUT_S, SinkError, new_recording, open_output
from thermal_comp_common import plain_output
from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.bags.reader import BagReadError, read_bag


def _wait_for_interrupt() -> None:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    while not stop.wait(0.5):
        pass


def error_components(contents) -> list[str]:
    """Component names of the first ThermalErrors message of each error topic, in order."""
    store = msg_definitions.typestore()
    comps: list[str] = []
    seen: set[str] = set()
    for m in contents.messages:
        if m.type == "thermal_comp_msgs/msg/ThermalErrors" and m.topic not in seen:
            seen.add(m.topic)
            try:
                names = store.deserialize_cdr(m.data, m.type).component_names
            except Exception:   # undecodable: reported when logging
                continue
            comps += [c for c in names if c not in comps]
    return comps


def bag_namespace(contents) -> str:
    """The cell namespace of the bag's thermal-comp topics ('' for the root namespace)."""
    for t in sorted({m.topic for m in contents.messages}):
        ns, _ = split_topic(t)
        if ns:
            return ns
    return ""


def arrivals(messages) -> dict[int, int]:
    """Health records (``/rosout``, ``/diagnostics``) -> the simulated instant each arrived: the
    newest data stamp among the data messages received (bag log time) at or before it. Keyed by
    the index in ``messages``; records received before any data are left out."""
    data = sorted((m.log_time_ns, m.stamp_ns) for m in messages if m.type not in FOREIGN_TYPES)
    if not data:
        return {}
    received = np.fromiter((d[0] for d in data), dtype=np.int64, count=len(data))
    newest = np.maximum.accumulate(np.fromiter((d[1] for d in data), dtype=np.int64, count=len(data)))
    out = {}
    for i, m in enumerate(messages):
        if m.type in FOREIGN_TYPES:
            k = int(np.searchsorted(received, m.log_time_ns, side="right")) - 1
            if k >= 0:
                out[i] = int(newest[k])
    return out


def log_bag(contents, rec: rr.RecordingStream, layout=None, progress: bool = True) -> tuple[int, str | None]:
    """Log every message of a bag (``bag_player.BagContents``) to ``rec``, in columns (one
    ``rr.send_columns`` per entity at the end); (messages logged, damage report or None)."""
    store = msg_definitions.typestore()
    logger = RerunLogger(rec, layout, columnar=True)
    msgs = contents.messages
    arrived = arrivals(msgs)
    bar = plain_output.progress(len(msgs), "view", "msg") if progress else None
    n = 0
    undecodable: set[str] = set()
    for i, m in enumerate(msgs):
        if bar is not None:
            bar.advance()
        try:
            full = msg_definitions.ensure_known(m.type)
            msg = store.deserialize_cdr(m.data, full)
        except Exception as exc:   # one bad message or unknown type must not stop the view
            if m.topic not in undecodable:
                undecodable.add(m.topic)
                print(f"warning: {m.topic}: cannot decode {m.type}: {exc}", file=sys.stderr)
            continue
        logger.log(m.topic, full, msg, m.stamp_ns, arrived.get(i))
        n += 1
    if bar is not None:
        bar.close()
    logger.send_columns()
    return n, contents.damage


def bag_to_rrd(bag, rrd, layout=None, app_id: str = "thermal_comp") -> tuple[int, str | None]:
    """Write a whole bag into the .rrd file ``rrd`` with the view's default blueprint (the
    bag's namespace and error components); (messages logged, damage report or None)."""
    contents = read_bag(bag)
    rec = new_recording(app_id)
    rec.save(str(rrd), default_blueprint=default_blueprint(bag_namespace(contents),
                                                             error_components(contents)))
    n, damage = log_bag(contents, rec, layout, progress=False)
    rec.flush()
    rec.disconnect()
    return n, damage


def run(args) -> int:
    """Show or write what the parsed arguments say; the exit code (0 shown, 2 bad arguments or
    unreadable bag, 3 the bag is damaged)."""
    try:
        layout = resolve_layout(args.layout) if args.layout else None
    except LayoutError as exc:
        print(f"thermal-comp view: {exc}", file=sys.stderr)
        return 2
    if args.rrd and pathlib.Path(args.rrd).exists() and not args.force:
        print(f"thermal-comp view: --rrd {args.rrd!r} exists already; not overwriting "
              "(--force replaces it)", file=sys.stderr)
        return 2
    spawn = args.spawn or not (args.rrd or args.serve_web)
    contents = None
    if args.bag:
        try:
            contents = read_bag(args.bag)
        except BagReadError as exc:
            print(f"thermal-comp view: {exc}", file=sys.stderr)
            return 2
    namespace = args.namespace or (bag_namespace(contents) if contents else "")
    blueprint = default_blueprint(namespace, error_components(contents) if contents else ())
    try:
        output = open_output(rrd=args.rrd, spawn=spawn, serve_web=args.serve_web, web_port=args.web_port,
                             grpc_port=args.grpc_port, blueprint=blueprint)
    except SinkError as exc:
        print(f"thermal-comp view: {exc}", file=sys.stderr)
        return 2
    rec = output.recording
    if output.web_url:
        print(f"rerun web viewer: {output.web_url}", flush=True)
    if contents is not None:
        n, damage = log_bag(contents, rec, layout, progress=not args.no_progress)
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        print(f"{args.bag}: {n} messages logged" + (f" to {args.rrd}" if args.rrd else ""), flush=True)
        if damage:
            print(f"warning: bag damaged, shown up to there: {damage}", file=sys.stderr)
        if args.serve_web:
            _wait_for_interrupt()
        output.close()
        return 3 if damage else 0
    from thermal_comp.view import rerun_view_node  # rclpy: only for the live topics
    return rerun_view_node.run(output, layout, ["thermal-comp-view", "--ros-args", *args.ros_args])
