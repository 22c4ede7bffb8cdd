"""``thermal-comp rtd-emulator``: serve the Modbus RTD modules of a sensor YAML with the rows
of a recording CSV, or with the running twin's readings (``--twin``, an rclpy node here).
See docs/sensors.md ("The RTD emulator")."""
from __future__ import annotations

import argparse
import math
import sys

from thermal_comp_common.command_line import run_parsed


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="thermal-comp rtd-emulator",
        description="Serve the Modbus RTD modules of a sensor YAML (register map, unit ids, "
                    "ports) with temperatures from a recording CSV or from the running twin, "
                    "for bench setups and tests.")
    p.add_argument("--config", required=True,
                   help="sensor YAML with sensors[].modbus and modbus.modules, or a shipped one by name "
                        "(rtd_bench)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--csv", help="recording CSV (shared format); column = channel + '_c'")
    src.add_argument("--twin", action="store_true",
                     help="serve machine_sim's live twin/sensor_readings (ROS; matched by channel); "
                          "ROS arguments may follow after --ros-args")
    p.add_argument("--speed", type=float, default=1.0,
                   help="playback speed: recording seconds per wall second (default 1)")
    p.add_argument("--loop", action="store_true", help="start over at the end of the recording")
    p.add_argument("--hold", action="store_true",
                   help="after the last row keep serving it until Ctrl-C (a stuck value: clients "
                        "will flag it stale) instead of exiting")
    return p


def main(argv: list[str] | None = None) -> int:
    """Emulate Pt100/RTD Modbus modules on loopback, serving temperatures from a CSV or the twin."""
    p = _parser()
    args, ros_args = p.parse_known_args(argv)
    if ros_args and not (args.twin and ros_args[0] == "--ros-args"):
        p.error(f"unrecognized arguments: {' '.join(ros_args)}")
    if not (args.speed > 0 and math.isfinite(args.speed)):
        p.error(f"--speed: {args.speed!r} must be > 0")
    return run_parsed("thermal_sensors.rtd_emulator_serve:run", args, ros_args)


if __name__ == "__main__":
    sys.exit(main())
