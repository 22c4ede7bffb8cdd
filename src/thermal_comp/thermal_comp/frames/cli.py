"""Print a machine's frame tree (what static_frames publishes on /tf_static), like tf2's view_frames.

``thermal-comp frames nmv5000`` or ``thermal-comp frames my_machine.yaml [--prefix cell_a/]``:
one line per frame, indented under its parent, with its translation from the parent and its
origin in ``machine_base`` (m).
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.command_line import run_parsed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="thermal-comp frames", description=__doc__.split("\n\n")[0])
    ap.add_argument("machine", help="twin preset (nmv5000, swiss-lathe, ...) or a YAML file with nodes/sensors")
    ap.add_argument("--prefix", default="", help="frame id prefix, e.g. cell_a/")
    args = ap.parse_args(argv)
    return run_parsed("thermal_comp.frames.tree_text:run", args)


if __name__ == "__main__":
    sys.exit(main())
