"""Record topics into a rosbag2 MCAP bag (metadata.yaml + zstd-chunked .mcap) until Ctrl-C."""
from __future__ import annotations

import argparse
import pathlib
import sys

from thermal_comp import bag_recorder_node


def build_parser() -> argparse.ArgumentParser:
    known = ", ".join(sorted({**bag_recorder_node.DEFAULT_TOPICS, **bag_recorder_node.OPTIONAL_TOPICS}))
    ap = argparse.ArgumentParser(
        prog="thermal-comp record", description=__doc__,
        epilog=f"Known topics (relative names take the namespace, see --ros-args): {known}. "
               "Other topics need their type: NAME:pkg/msg/Type. Stop with Ctrl-C or SIGTERM; "
               "the bag is closed cleanly. A killed recorder leaves a bag that "
               "'thermal-comp play' replays up to the last flushed chunk.")
    ap.add_argument("out", metavar="OUT", help="bag folder to create (must not exist)")
    ap.add_argument("topics", nargs="*", metavar="TOPIC",
                    help="topics to record (default: every thermal-comp topic except sim_sync)")
    ap.add_argument("--flush-period", type=float, default=1.0, metavar="S",
                    help="close the open chunk every S seconds of wall time (default 1)")
    ap.add_argument("--timestamps", choices=("header", "receive"), default="header",
                    help="bag time of a message: its header stamp (default, deterministic in "
                         "simulated time) or the receive time")
    ap.add_argument("--use-sim-time", action="store_true",
                    help="receive times on /clock time (only matters with --timestamps receive)")
    ap.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    ap.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                    help="further ROS arguments, e.g. -r __ns:=/cell1")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if pathlib.Path(args.out).exists():
        print(f"thermal-comp record: OUT {args.out!r} exists already; not overwriting", file=sys.stderr)
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


if __name__ == "__main__":
    raise SystemExit(main())
