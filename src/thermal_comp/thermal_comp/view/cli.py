"""Show topics or a bag in rerun: spawned viewer, web viewer on localhost, or an .rrd file."""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.command_line import run_parsed


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


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    return run_parsed("thermal_comp.view.run:run", args)

if __name__ == "__main__":
    raise SystemExit(main())
