"""Calibrate a twin on a recording: ``thermal-comp calibrate --twin M --recording REC --out DIR``.

Fits the twin's existing parameters (ranges from the machine's ``calibration`` section or
``--bounds``) on the training window, scores the held-out rest, and writes
``DIR/twin_calibrated.yaml``, ``DIR/report.md``, ``DIR/report.json`` and PNG plots. The
Jacobian's finite-difference columns can run on a local process pool (``--jobs N``) or a Dask
cluster (``--engine dask [--address tcp://HOST:8786]``); the answer is the same on every engine
(docs/distributed.md). Several recordings (files, a folder, a glob or a manifest) are runs:
fitted together, every run from its own initial state, the held-out runs scored out of sample
(docs/calibrate.md, "Several runs"); ``--runs-split`` takes evaluate's split grammar, one fit per
fold, the folds one after the other. Default serial: a Jacobian is ~40 twin runs of a few ms, and a pool per
Jacobian cost more CPU than it saved on FL_THERMAL (docs/diagnose.md, Speed).
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.runtime.engine_options import add_engine_arguments
from thermal_comp_common.bags.truncation import add_allow_truncated_argument, truncated_bags_allowed
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--twin", required=True, help="machine YAML file or preset name (e.g. spindle-stand)")
    p.add_argument("--recording", required=True, nargs="+", metavar="SOURCE",
                   help="recording CSV or rosbag2 MCAP bag; several recordings, a folder, a glob or a manifest "
                        "(YAML or CSV with a path column, as evaluate takes) are runs fitted together, split by run")
    p.add_argument("--out", required=True, help="output directory (must be new or empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty --out")
    p.add_argument("--bounds", help="YAML file with a calibration section (kinds, parameters); "
                                    "replaces the machine's own")
    p.add_argument("--holdout-fraction", type=float, default=None,
                   help="one recording: last fraction kept out of the fit (default 1/3)")
    p.add_argument("--holdout-runs", default=None, metavar="K|NAME,NAME",
                   help="several runs: the last K runs, or the named runs, kept out of the fit "
                        "(default the last third, at least one)")
    p.add_argument("--runs-split", default=None, metavar="HOW",
                   help="several runs, as evaluate's --runs-split: TRAIN,VAL,TEST fractions, loro, by:FIELD, "
                        "by:FIELD=VALUE or test=NAME,...; one fit per fold; with several folds the twin written "
                        "is fitted on all runs (docs/calibrate.md)")
    p.add_argument("--initial-state", choices=("steady", "readings"), default="steady",
                   help="where every recording starts the twin: its idle equilibrium (a machine at rest) or where "
                        "the recording's first readings put it, its displacements then relative to its first row "
                        "(a recording that starts warm; docs/calibrate.md, \"Warm starts\")")
    p.add_argument("--max-nfev", type=int, default=20,
                   help="at most this many optimiser iterations (default 20)")
    p.add_argument("--block-min", type=float, default=30.0,
                   help="block length of an input estimated from the temperatures (min, default 30)")
    p.add_argument("--map", action="append", default=[], metavar="OLD=NEW|NAME*FACTOR",
                   help="rename a recording column to the twin's name, or scale one (e.g. ch3_um*-1 "
                        "flips its sign); repeatable")
    p.add_argument("--map-file", help="YAML column mapping {columns: {old: new}, scale: {name: factor}}")
    p.add_argument("--temperatures-topic", default="temperatures", help="bag only")
    p.add_argument("--errors-topic", default="errors/ground_truth", help="bag only")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_sample_period_argument(p)
    add_allow_truncated_argument(p)
    add_engine_arguments(p, what="Jacobian columns")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with truncated_bags_allowed(args.allow_truncated):
        return run_parsed("thermal_twin.calibrate.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
