"""Record topics into a rosbag2 MCAP bag (metadata.yaml + zstd-chunked .mcap) until Ctrl-C;
or repair a bag cut by kill -9 (--repair) so that every standard reader opens it."""
from __future__ import annotations

import argparse
import pathlib
import sys

from thermal_comp.bags import recorder_node as bag_recorder_node
from thermal_comp_common.bags.writer import BagWriteError, remove_bag_folder


def build_parser() -> argparse.ArgumentParser:
    known = ", ".join(sorted({**bag_recorder_node.DEFAULT_TOPICS, **bag_recorder_node.OPTIONAL_TOPICS}))
    ap = argparse.ArgumentParser(
        prog="thermal-comp record", description=__doc__,
        epilog=f"Known topics (relative names take the namespace, see --ros-args): {known}. "
               "Other topics need their type: NAME:pkg/msg/Type. Stop with Ctrl-C or SIGTERM; "
               "the bag is closed cleanly. A killed recorder leaves a bag that "
               "'thermal-comp play' replays up to the last flushed chunk and that "
               "'thermal-comp record --repair OUT' turns into a complete one. Exit codes: 0 recorded "
               "(or repaired, or intact), 2 bad arguments, OUT exists (without --force) or is no bag "
               "(--repair), 1 recording error.")
    ap.add_argument("out", metavar="OUT", help="bag folder to create (must not exist, see --force)")
    ap.add_argument("--force", action="store_true",
                    help="replace an existing bag folder OUT (only a bag or an empty folder)")
    ap.add_argument("--repair", action="store_true",
                    help="do not record: rewrite the bag OUT cut by kill -9 into a complete one "
                         "(the damaged original is kept as OUT.damaged)")
    ap.add_argument("topics", nargs="*", metavar="TOPIC",
                    help="topics to record (default: every thermal-comp topic except sim_sync)")
    ap.add_argument("--flush-period", type=float, default=1.0, metavar="S",
                    help="close the open chunk every S seconds of wall time (default 1)")
    ap.add_argument("--timestamps", choices=("header", "receive"),
                    default=bag_recorder_node.DEFAULT_TIMESTAMPS,
                    help="bag log time of a message: the receive time on the recorder's clock "
                         "(default, as ros2 bag record and the cell's recorder node write it) or "
                         "its header stamp; readers key instants by the header stamp either way")
    ap.add_argument("--use-sim-time", action="store_true",
                    help="receive times on /clock time (only matters with --timestamps receive)")
    ap.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    ap.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                    help="further ROS arguments, e.g. -r __ns:=/cell1")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.repair:
        return _repair(args.out)
    out = pathlib.Path(args.out)
    if out.exists():
        if not args.force:
            print(f"thermal-comp record: OUT {args.out!r} exists already; not overwriting "
                  "(--force replaces it)", file=sys.stderr)
            return 2
        try:
            remove_bag_folder(out)
        except BagWriteError as exc:
            print(f"thermal-comp record: {exc}", file=sys.stderr)
            return 2
    for t in args.topics:
        try:
            bag_recorder_node.parse_topic_arg(t)
        except ValueError as exc:
            print(f"thermal-comp record: {exc}", file=sys.stderr)
            return 2
    topics = "[" + ",".join(f"'{t}'" for t in args.topics) + "]" if args.topics else "['']"
    ros = ["thermal-comp-record", "--ros-args",
           "-p", f"output:={args.out}", "-p", f"topics:={topics}",
           "-p", f"flush_period_s:={float(args.flush_period)}",
           "-p", f"timestamps:={args.timestamps}", "-p", f"compression:={args.compression}",
           "-p", f"use_sim_time:={'true' if args.use_sim_time else 'false'}"] + list(args.ros_args)
    return bag_recorder_node.main(ros)


def _repair(out: str) -> int:
    # only with --repair
    from thermal_comp_common.bags.reader import BagReadError
    from thermal_comp_common.bags.repair import repair_bag
    try:
        r = repair_bag(out)
    except (BagReadError, FileExistsError, OSError) as exc:
        print(f"thermal-comp record --repair: {exc}", file=sys.stderr)
        return 2
    if r.damage is None:
        print(f"{r.path}: intact ({r.messages} messages); nothing to repair")
    else:
        print(f"{r.path}: repaired, {r.messages} messages kept (was: {r.damage}); "
              f"the damaged original is kept as {r.kept_as}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
