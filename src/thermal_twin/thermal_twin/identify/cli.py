"""``thermal-comp twin init``: a starting twin for a machine without a preset.

From a recording (CSV or cell bag: temperatures, machine inputs, sparse probes or continuous
displacement columns) and a short description (YAML: which sensor sits on which body, which
inputs heat where, which displacement channels in which direction, the hall sensor), identify a
lumped thermal twin and write it in the project's machine format (docs/twin_init.md).
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp twin", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="action", required=True)
    i = sub.add_parser("init", help="identify a lumped twin from a recording and a description")
    i.add_argument("--recording", required=True, help="recording CSV or cell bag (probes from errors/measured)")
    i.add_argument("--description", required=True, help="description YAML (docs/twin_init.md)")
    i.add_argument("--out", required=True, help="output folder (new or empty unless --force)")
    i.add_argument("--hours", type=float, help="use only the first H hours of the recording")
    i.add_argument("--holdout", type=float, default=0.25,
                   help="last fraction kept out of a second fit of the kept structure, for the held-out figures (default 0.25)")
    i.add_argument("--max-nfev", type=int, default=40, help="optimiser iterations per pass (default 40)")
    i.add_argument("--force", action="store_true", help="write into a non-empty --out")
    i.add_argument("--quiet", action="store_true", help="no progress lines")
    add_sample_period_argument(i)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_parsed("thermal_twin.identify.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
