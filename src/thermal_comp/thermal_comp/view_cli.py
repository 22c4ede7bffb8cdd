"""Show topics or a bag in rerun: spawned viewer, web viewer on localhost, or an .rrd file."""
from __future__ import annotations

import argparse
import os
import pathlib
import signal
import sys
import threading

import rerun as rr

APP_ID = "thermal_comp"
#: never hang at exit on a viewer that went away
FLUSH_TIMEOUT_S = 30.0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="thermal-comp view", description=__doc__,
        epilog="Without BAG the live topics of the cell are shown (a ROS node subscribes to every "
               "thermal-comp topic). With BAG its messages are logged on the sim_time timeline. "
               "Examples: 'thermal-comp view bags/fl_thermal_2h --rrd out/fl.rrd', "
               "'thermal-comp view --serve-web'. Sensor layout: --layout FILE with "
               "sensors: {ID: {position_mm: [x, y, z]}} or a twin preset name; without it the "
               "preset whose sensor ids match is used, else a schematic ring.")
    ap.add_argument("bag", nargs="?", metavar="BAG", help="bag folder or .mcap file (default: live topics)")
    ap.add_argument("--rrd", metavar="OUT", help="write an .rrd recording to OUT")
    ap.add_argument("--spawn", action="store_true", help="spawn the native rerun viewer (default "
                    "when neither --rrd nor --serve-web is given)")
    ap.add_argument("--serve-web", action="store_true",
                    help="serve rerun's web viewer on localhost (until Ctrl-C)")
    ap.add_argument("--web-port", type=int, default=9090, help="web viewer port (default 9090)")
    ap.add_argument("--grpc-port", type=int, default=9876, help="rerun gRPC port (default 9876)")
    ap.add_argument("--layout", metavar="FILE|PRESET", help="sensor layout YAML or twin preset name "
                    "(default: the preset whose sensors match, else a schematic ring)")
    ap.add_argument("--namespace", default="", help="cell namespace for the default blueprint")
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
    from thermal_comp import msg_definitions
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


def log_bag(contents, rec: rr.RecordingStream, layout=None, progress: bool = True) -> tuple[int, str | None]:
    """Log every message of a bag (``bag_player.BagContents``) to ``rec``;
    (messages logged, damage report or None)."""
    from thermal_comp import msg_definitions
    from thermal_comp.rerun_logging import RerunLogger
    store = msg_definitions.typestore()
    logger = RerunLogger(rec, layout)
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
        logger.log(m.topic, full, msg, m.log_time_ns)
        n += 1
    return n, contents.damage


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from thermal_comp.rerun_logging import LayoutError, default_blueprint, resolve_layout
    try:
        layout = resolve_layout(args.layout) if args.layout else None
    except LayoutError as exc:
        print(f"thermal-comp view: {exc}", file=sys.stderr)
        return 2
    spawn = args.spawn or not (args.rrd or args.serve_web)
    if spawn and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                           or os.environ.get("WAYLAND_DISPLAY")):
        print("thermal-comp view: no display for the native viewer (DISPLAY / WAYLAND_DISPLAY unset); "
              "use --serve-web (browser) or --rrd OUT", file=sys.stderr)
        return 2
    contents = None
    if args.bag:
        from thermal_comp.bag_player import BagReadError, read_bag
        try:
            contents = read_bag(args.bag)
        except BagReadError as exc:
            print(f"thermal-comp view: {exc}", file=sys.stderr)
            return 2
    blueprint = default_blueprint(args.namespace, error_components(contents) if contents else ())
    rec = rr.RecordingStream(APP_ID, recording_id=None)
    sinks = []
    server = None
    if args.rrd:
        sinks.append(rr.FileSink(args.rrd))
    if args.serve_web:
        server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=args.grpc_port)
        sinks.append(server)
    if spawn:
        port = args.grpc_port + 1 if args.serve_web else args.grpc_port
        viewer = pathlib.Path(sys.executable).parent / "rerun"   # the venv's viewer, PATH or not
        try:
            rr.spawn(port=port, connect=False, recording=rec,
                     executable_path=str(viewer) if viewer.is_file() else None)
        except RuntimeError as exc:
            print(f"thermal-comp view: cannot spawn the rerun viewer: {str(exc).splitlines()[0]} "
                  f"(use --rrd OUT or --serve-web)", file=sys.stderr)
            return 2
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    rec.set_sinks(*sinks, default_blueprint=blueprint)
    if server is not None:
        rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=server.uri)
        print(f"rerun web viewer: http://localhost:{args.web_port}/?url={server.uri}", flush=True)
    if contents is not None:
        n, damage = log_bag(contents, rec, layout, progress=not args.no_progress)
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        print(f"{args.bag}: {n} messages logged" + (f" to {args.rrd}" if args.rrd else ""), flush=True)
        if damage:
            print(f"warning: bag damaged, shown up to there: {damage}", file=sys.stderr)
        if args.serve_web:
            _wait_for_interrupt()
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        rec.disconnect()
        return 3 if damage else 0
    from thermal_comp import rerun_view_node
    code = rerun_view_node.main(rec, layout, ["thermal-comp-view", "--ros-args", *args.ros_args])
    rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    rec.disconnect()
    return code


if __name__ == "__main__":
    raise SystemExit(main())
