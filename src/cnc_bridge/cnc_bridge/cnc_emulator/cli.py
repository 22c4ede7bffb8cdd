"""``thermal-comp cnc-emulator``: the emulated CNC from the command line.

Secrets never go on the command line (``ps`` shows it): the user, password and the server's
private key come from ``--credentials-file`` (mode 600) or the THERMAL_COMP_OPCUA_*
environment (:mod:`cnc_bridge.credentials`). With ``--twin`` the emulator is fed by the
running twin over ROS (an rclpy node in this process).
"""
from __future__ import annotations

import argparse
import math
import sys

from cnc_bridge.cnc_emulator.axes import DEFAULT_COMPENSATION_AXES, DEFAULT_POSITION_AXES
from thermal_comp_common.command_line import run_parsed


def _parse_errors(text: str) -> dict[str, float]:
    out = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--true-errors: '{item}' is not NAME=NUMBER") from None
        if not sep or not math.isfinite(out[name.strip()]):
            raise argparse.ArgumentTypeError(f"--true-errors: '{item}' is not NAME=NUMBER")
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="thermal-comp cnc-emulator",
        description="OPC UA CNC emulator: axis positions and SINUMERIK-like temperature-"
                    "compensation nodes (SD43900/43910/43920, MD32750) on 127.0.0.1; "
                    "optional ProbeMove method. Node ids: see docs/cnc_bridge.md.")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=4840, help="TCP port (default 4840)")
    p.add_argument("--credentials-file",
                   help="YAML {user, password, private_key} readable by its owner only (mode 600): "
                        "the user a client must log in as and the private key of --certificate; "
                        "default: THERMAL_COMP_OPCUA_USER/PASSWORD/PRIVATE_KEY environment")
    p.add_argument("--certificate", help="server certificate (DER or PEM) for Basic256Sha256")
    p.add_argument("--client-trust", action="append", default=[],
                   help="trusted client certificate file or folder (repeatable): the trust list")
    p.add_argument("--security", choices=("required", "optional"), default="optional",
                   help="required: only Basic256Sha256 Sign&Encrypt connections with a trusted "
                        "client certificate and a user login are accepted")
    p.add_argument("--offset-limit-mm", type=float, default=None,
                   help="largest |SD43900| offset the CNC accepts, mm (default 1.0)")
    p.add_argument("--axes", default=",".join(DEFAULT_POSITION_AXES),
                   help="axes with a position node (comma-separated)")
    p.add_argument("--compensation-axes", default=",".join(DEFAULT_COMPENSATION_AXES),
                   help="axes with temperature-compensation nodes, e.g. X,Y,Z or GB_X,T01_X")
    p.add_argument("--probe-artefact", action="store_true",
                   help="offer ProbeMove, answered by the twin's artefact geometry with the "
                        "errors of --true-errors and the compensation currently applied")
    p.add_argument("--true-errors", type=_parse_errors, default={},
                   help="true thermal errors for --probe-artefact, e.g. E_Z0T=12,E_Y0C=-4 "
                        "(um, um/m)")
    p.add_argument("--twin", action="store_true",
                   help="feed the emulator from the running twin over ROS: machine_state -> axis "
                        "positions, errors/ground_truth -> ProbeMove answers (implies ProbeMove); "
                        "ROS arguments follow --ros-args")
    p.add_argument("-v", "--verbose", action="store_true", help="log every session and write")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:
        k = argv.index("--ros-args")
        argv, ros_args = argv[:k], argv[k:]
    args = build_parser().parse_args(argv)
    if ros_args and not args.twin:
        print("cnc-emulator: --ros-args only with --twin", file=sys.stderr)
        return 2
    return run_parsed("cnc_bridge.cnc_emulator.command:run", args, ros_args)
