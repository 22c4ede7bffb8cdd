"""Simulate a machine cell offline and write a recording CSV (`thermal-comp sim`).

Example: thermal-comp sim --machine nmv5000 --scenario talc-178h-dry --csv out.csv
Columns: time_s, the machine's inputs, <sensor>_c readings, true error components
(docs/twin.md).
"""
from __future__ import annotations

import argparse
import sys

from thermal_twin.machine.presets import preset_names
from thermal_twin.sim.scenarios import SCENARIOS
from thermal_comp_common.command_line import run_parsed


def build_parser() -> argparse.ArgumentParser:
    scen = "; ".join(f"{n} ({', '.join(b.replace('_', '-') for b in s.builders)})"
                     for n, s in sorted(SCENARIOS.items()))
    p = argparse.ArgumentParser(
        prog="thermal-comp sim", description=__doc__.splitlines()[0],
        epilog=f"presets: {', '.join(preset_names())}. scenarios (machines): {scen}.")
    p.add_argument("--machine", required=True,
                   help="preset name (nmv5000, swiss-lathe, spindle-stand, fe-three-body) or a machine YAML file")
    p.add_argument("--scenario", required=True, help="scenario name (see below)")
    p.add_argument("--hours", type=float, default=None, help="duration in hours (default: the scenario's)")
    p.add_argument("--seed", type=int, default=0, help="random seed of scenario and sensor noise (default 0)")
    p.add_argument("--step", type=float, default=None, help="time step in s (default: the scenario's)")
    p.add_argument("--csv", required=True, help="output recording CSV")
    p.add_argument("--plot", default=None, help="also write a PNG overview (inputs, readings, errors)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_parsed("thermal_twin.sim.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
