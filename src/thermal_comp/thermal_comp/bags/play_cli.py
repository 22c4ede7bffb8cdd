"""Replay a rosbag2 MCAP bag: re-publish its messages and drive /clock in simulated time."""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.command_line import run_parsed


def _list(values: list[str]) -> str:
    return "[" + ",".join(f"'{v}'" for v in values) + "]" if values else "['']"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="thermal-comp play", description=__doc__,
        epilog="Exit codes: 0 replayed completely, 3 the bag is damaged (replayed up to the "
               "damage, which is reported), 2 bad arguments or unreadable bag, 1 playback error.")
    ap.add_argument("bag", metavar="BAG", help="bag folder (metadata.yaml + .mcap) or .mcap file")
    pace = ap.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, metavar="R",
                      help="bag seconds per wall second (default 1)")
    pace.add_argument("--as-fast-as-possible", action="store_true",
                      help="no wall-clock pacing; every instant is acknowledged by the subscribers "
                           "(reliable QoS: delivered into their queues) and processed by the "
                           "--lockstep nodes (SimSync) before the next")
    ap.add_argument("--topics", nargs="+", default=[], metavar="TOPIC",
                    help="replay only these topics (resolved names, e.g. /temperatures)")
    ap.add_argument("--wait-for-subscribers", type=int, default=0, metavar="N",
                    help="wait until each topic has N subscribers before starting")
    ap.add_argument("--match-timeout", type=float, default=10.0, metavar="S",
                    help="start anyway after S seconds of waiting for subscribers")
    ap.add_argument("--lockstep", nargs="+", default=[], metavar="NODE",
                    help="nodes whose SimSync must acknowledge each instant (with --as-fast-as-possible)")
    ap.add_argument("--clock-hz", type=float, default=10.0,
                    help="/clock updates per wall second between messages (with --rate)")
    ap.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[],
                    help="further ROS arguments, e.g. -r __ns:=/cell1")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if not args.rate > 0:
        print(f"thermal-comp play: --rate {args.rate!r} must be > 0", file=sys.stderr)
        return 2
    ros = ["thermal-comp-play", "--ros-args",
           "-p", f"bag:={args.bag}", "-p", f"rate:={float(args.rate)}",
           "-p", f"as_fast_as_possible:={'true' if args.as_fast_as_possible else 'false'}",
           "-p", f"clock_hz:={float(args.clock_hz)}", "-p", f"topics:={_list(args.topics)}",
           "-p", f"wait_for_subscribers:={int(args.wait_for_subscribers)}",
           "-p", f"match_timeout_s:={float(args.match_timeout)}",
           "-p", f"lockstep_participants:={_list(args.lockstep)}",
           "-p", f"progress:={'true' if sys.stderr.isatty() else 'false'}"] + list(args.ros_args)
    return run_parsed("thermal_comp.bags.player_node:main", ros)


if __name__ == "__main__":
    raise SystemExit(main())
