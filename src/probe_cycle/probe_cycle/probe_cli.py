"""The arguments of one probing cycle as a command line offers them (the goal's fields, the
server's namespace, the waits): ``thermal-comp probe`` (thermal_comp.cell.inspect_cli, through the
Cell API) builds on this parser.
"""
from __future__ import annotations

import argparse


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp probe", description="Run one probing cycle on a running "
                                "probe_cycle server and print the measured errors.")
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
