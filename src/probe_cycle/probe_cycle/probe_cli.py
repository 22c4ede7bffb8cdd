"""Run one probing cycle on a running probe_cycle server and print the measured errors.

``thermal-comp probe [--guide-bush] [--set-reference] [--points N] [--angles 0,90,180,270,360]
[--timeout S] [--namespace NS] [--wait S]``. It shows a progress bar per point and
prints the errors with their expanded uncertainty U (k=2). Exit code: 0 if the cycle
succeeded, 1 if it failed or was refused, 2 on bad arguments or when no server answers.
"""
from __future__ import annotations

import argparse
import math
import sys

from thermal_comp_common.command_line import run_parsed


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp probe", description=__doc__.split("\n\n")[0])
    p.add_argument("--guide-bush", action="store_true",
                   help="probe the guide bush (lathe) instead of the sphere (5-axis)")
    p.add_argument("--set-reference", action="store_true",
                   help="this cycle becomes the reference (zero) of later cycles")
    p.add_argument("--points", type=int, default=0,
                   help="touch points per C indexing (sphere) or repeats (guide bush); 0 = default")
    p.add_argument("--angles", default="",
                   help="C indexings in degrees, comma-separated (default 0,90,180,270,360)")
    p.add_argument("--timeout", type=float, default=0.0,
                   help="cycle timeout on the machine's clock, s (0 = server default)")
    p.add_argument("--namespace", default="", help="cell namespace of the server, e.g. /cell1")
    p.add_argument("--wait", type=float, default=10.0,
                   help="wall-clock seconds to wait for the server to appear (default 10)")
    p.add_argument("--deadline", type=float, default=600.0,
                   help="wall-clock seconds to wait for the result (default 600)")
    return p


def _angles(text: str) -> list[float]:
    out = []
    for item in filter(None, (t.strip() for t in text.split(","))):
        try:
            v = float(item)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--angles: '{item}' is not a number") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"--angles: '{item}' is not finite")
        out.append(v)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        angles = _angles(args.angles)
    except argparse.ArgumentTypeError as exc:
        print(f"thermal-comp probe: {exc}", file=sys.stderr)
        return 2
    if args.points < 0:
        print(f"thermal-comp probe: --points: {args.points} is negative", file=sys.stderr)
        return 2
    return run_parsed("probe_cycle.probe_client:run", args, angles)


if __name__ == "__main__":
    sys.exit(main())
