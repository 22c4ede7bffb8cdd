"""Show topics or a bag in rerun: spawned viewer, web viewer on localhost, or an .rrd file."""
from __future__ import annotations

import argparse
import pathlib
import signal
import sys
import threading

import rerun as rr



def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="thermal-comp view", description=__doc__,
        epilog="Without BAG the live topics of the cell are shown (a ROS node subscribes to every "
               "thermal-comp topic). With BAG its messages are logged on the sim_time timeline. "
               "Examples: 'thermal-comp view bags/fl_thermal_2h --rrd out/fl.rrd', "
               "'thermal-comp view --serve-web'. Sensor layout: --layout FILE with "
               "sensors: {ID: {position_mm: [x, y, z]}} or a twin preset name; without it the "
               "preset whose sensor ids match is used, else a schematic ring. Exit codes: 0 shown "
               "(or written), 3 the bag is damaged (shown up to the damage, which is reported), 2 bad "
               "arguments, unreadable bag or an existing --rrd file (without --force).")
    ap.add_argument("bag", nargs="?", metavar="BAG", help="bag folder or .mcap file (default: live topics)")
    ap.add_argument("--rrd", metavar="OUT", help="write an .rrd recording to OUT (must not exist, see --force)")
    ap.add_argument("--force", action="store_true", help="replace an existing --rrd file")
    ap.add_argument("--spawn", action="store_true", help="spawn the native rerun viewer (default "
                    "when neither --rrd nor --serve-web is given)")
    ap.add_argument("--serve-web", action="store_true",
                    help="serve rerun's web viewer on localhost (until Ctrl-C)")
    ap.add_argument("--web-port", type=int, default=9090, help="web viewer port (default 9090)")
    ap.add_argument("--grpc-port", type=int, default=9876, help="rerun gRPC port (default 9876)")
    ap.add_argument("--layout", metavar="FILE|PRESET", help="sensor layout YAML or twin preset name "
                    "(default: the preset whose sensors match, else a schematic ring)")
    ap.add_argument("--namespace", default="", help="cell namespace for the default blueprint "
                    "(default: the bag's)")
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                    help="(live mode) further ROS arguments, e.g. -r __ns:=/cell1")
    return ap


def _wait_for_interrupt() -> None:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    while not stop.wait(0.5):
        pass


def error_components(contents) -> list[str]:
    """Component names of the first ThermalErrors message of each error topic, in order."""
    from thermal_comp_common import msg_definitions
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
    from thermal_comp.rerun_logging import split_topic
    for t in sorted({m.topic for m in contents.messages}):
        ns, _ = split_topic(t)
        if ns:
            return ns
    return ""


def log_bag(contents, rec: rr.RecordingStream, layout=None, progress: bool = True) -> tuple[int, str | None]:
    """Log every message of a bag (``bag_player.BagContents``) to ``rec``, in columns (one
    ``rr.send_columns`` per entity at the end); (messages logged, damage report or None)."""
    from thermal_comp_common import msg_definitions
    from thermal_comp.rerun_logging import RerunLogger
    store = msg_definitions.typestore()
    logger = RerunLogger(rec, layout, columnar=True)
    msgs = contents.messages
    if progress:
        from tqdm import tqdm
        msgs = tqdm(msgs, desc="view", unit="msg", leave=False, file=sys.stderr)
    n = 0
    undecodable: set[str] = set()
    for m in msgs:
        try:
            full = msg_definitions.ensure_known(m.type)
            msg = store.deserialize_cdr(m.data, full)
        except Exception as exc:   # one bad message or unknown type must not stop the view
            if m.topic not in undecodable:
                undecodable.add(m.topic)
                print(f"warning: {m.topic}: cannot decode {m.type}: {exc}", file=sys.stderr)
            continue
        logger.log(m.topic, full, msg, m.stamp_ns)
        n += 1
    logger.send_columns()
    return n, contents.damage


def bag_to_rrd(bag, rrd, layout=None, app_id: str = "thermal_comp") -> tuple[int, str | None]:
    """Write a whole bag into the .rrd file ``rrd`` with the view's default blueprint (the
    bag's namespace and error components); (messages logged, damage report or None)."""
    from thermal_comp_common.bag_reader import read_bag
    from thermal_comp.rerun_logging import default_blueprint
    contents = read_bag(bag)
    rec = rr.RecordingStream(app_id)
    rec.save(str(rrd), default_blueprint=default_blueprint(bag_namespace(contents),
                                                             error_components(contents)))
    n, damage = log_bag(contents, rec, layout, progress=False)
    rec.flush()
    rec.disconnect()
    return n, damage


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from thermal_comp.rerun_logging import LayoutError, default_blueprint, resolve_layout
    from thermal_comp.rerun_sinks import FLUSH_TIMEOUT_S, SinkError, open_output
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
        from thermal_comp_common.bag_reader import BagReadError, read_bag
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
    from thermal_comp import rerun_view_node
    return rerun_view_node.run(output, layout, ["thermal-comp-view", "--ros-args", *args.ros_args])


if __name__ == "__main__":
    raise SystemExit(main())
