"""``thermal-comp evaluate REC --out DIR``: every model against honest baselines on your recording.

REC is a CSV (plain, with a BOM, or Excel-style ``;`` / decimal comma) or a bag. Columns: by
default the project's kinds (``*_c`` temperatures, ``*_um`` / ``E_*`` displacements, the rest
machine inputs); ``--temperatures/--displacements/--inputs`` take names or glob patterns,
``--map OLD=NEW`` / ``--map NAME*K`` / ``--map-file`` rename and scale (the calibrate mapping),
``--unit NAME=mm`` converts, ``--spec YAML`` holds all of it (docs/evaluate.md). Writes
evaluation.json, evaluation.png and evaluation.rrd into DIR and prints the table. Model rows run
serially, on ``--jobs N`` local processes or on a dask cluster (``--engine dask --address ...``).
Exit codes: 0 done, 2 bad input (named), 3 --out exists and is not empty (use --force).
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.runtime.engine_options import add_engine_arguments

from thermal_eval.evaluate.opt_in import OPT_IN
from thermal_comp_common.bags.truncation import add_allow_truncated_argument, truncated_bags_allowed
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp evaluate", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", metavar="REC", nargs="+",
                    help="recording CSV, bag folder or .mcap file; several, a folder of them, a glob or a manifest "
                         "(YAML / CSV with path, unit, programme, date, hall_setpoint_c) make a data set of runs")
    ap.add_argument("--runs-split", metavar="HOW",
                    help="several runs: TRAIN,VAL,TEST fractions of the runs (default 0.6,0.2,0.2, date order), "
                         "loro (leave one run out), by:FIELD (leave one group out), by:FIELD=VALUE, test=NAME,...")
    ap.add_argument("--segments", type=int, metavar="K",
                    help="cut each recording into K runs of equal rows (scores one long recording across runs)")
    ap.add_argument("--run-start", choices=("auto", "continued", "separate"), default="auto",
                    help="several runs: continued (one recording cut: absolute temperatures, dynamic state carried "
                         "from run to run) or separate (each run's temperatures relative to its first reading, "
                         "each run after --rest-h at rest); auto (default) decides from the temperatures' jump "
                         "between one run's end and the next one's start, and says so")
    ap.add_argument("--rest-h", type=float, default=None, metavar="H",
                    help="several runs: each starts after its first reading held H hours, so dynamic models start it "
                         "at rest (default: 3 for separate runs, 0 for continued ones)")
    add_sample_period_argument(ap)
    ap.add_argument("--out", required=True, metavar="DIR", help="output folder (refused if not empty, see --force)")
    ap.add_argument("--force", action="store_true", help="write into a non-empty --out")
    ap.add_argument("--spec", metavar="YAML", help="columns, units, split and mapping in one file")
    ap.add_argument("--temperatures", nargs="+", metavar="COL", help="temperature columns (names or globs)")
    ap.add_argument("--displacements", nargs="+", metavar="COL", help="displacement channels (names or globs)")
    ap.add_argument("--inputs", nargs="*", metavar="COL", help="machine inputs (none: --inputs with no name)")
    ap.add_argument("--map", action="append", default=[], metavar="OLD=NEW|NAME*K", help="rename / scale a column")
    ap.add_argument("--map-file", metavar="YAML", help="column mapping file (columns:, scale:)")
    ap.add_argument("--unit", action="append", default=[], metavar="COL=UNIT",
                    help="unit of a column: um mm nm m in (displacements), C K F (temperatures)")
    ap.add_argument("--split", metavar="TRAIN,VAL,TEST", help="fractions in time order (default 0.6,0.2,0.2)")
    ap.add_argument("--split-rows", metavar="TRAIN_END,BOUNDARY", help="first validation row and first test row")
    ap.add_argument("--test-first", action="store_true", help="the test window comes before the validation window")
    ap.add_argument("--models", nargs="+", metavar="NAME", help="only these models (baselines always run)")
    ap.add_argument("--also", nargs="+", default=[], metavar="NAME",
                    help=f"the default models plus these (opt-in: {', '.join(OPT_IN)})")
    ap.add_argument("--closed-loop", nargs="+", default=[], metavar="NAME",
                    help="also the project's adaptive models with their own logic, within the budget: "
                         "agp_closed_loop (sigma_max recalibration), talc_closed_loop (calibration, no-good, updates); calibrated on the training rows: "
                         "talc_calibrated[_inputs][_load_probing], agp_calibrated")
    ap.add_argument("--open-loop-only", action="store_true", help="no adaptive mode")
    ap.add_argument("--probe-every-h", type=float, default=2.0, help="scheduled probing interval (h)")
    ap.add_argument("--max-probes-per-h", type=float, default=1.0,
                    help="cap on all probings after calibration, average per hour")
    ap.add_argument("--tolerance-um", type=float, default=1.0,
                    help="predicted change since the last probing that asks for one")
    ap.add_argument("--probe-resolution-um", type=float, default=0.0,
                    help="your probe's resolution: a predicted change below it (or below twice the noise of "
                         "a reading difference measured on the training rows) is not acted on (default 0)")
    ap.add_argument("--probe-phases", type=int, default=1, metavar="K",
                    help="score the adaptive mode at K phases of the probing clock (delayed by i/K of the "
                         "interval, each a full run with its own probings): mean and worst per channel (default 1)")
    ap.add_argument("--load-probing", action="store_true",
                    help="each model may also probe a few minutes after a machine-input step (spindle speed, "
                         "coolant...), from a token bucket: at most 1 + max-probes-per-h x the hours after "
                         "calibration; off/on, delay and bucket depth chosen per model on the training rows")
    ap.add_argument("--bucket-credit", type=float, default=1.0, choices=(0.0, 1.0),
                    help="with --load-probing: probings the bucket holds when calibration ends (1: the total may "
                         "exceed max-probes-per-h x hours by one; 0: never more than the rate on average)")
    add_engine_arguments(ap, what="model rows")
    ap.add_argument("--no-rerun", action="store_true", help="no evaluation.rrd")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_allow_truncated_argument(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    with truncated_bags_allowed(args.allow_truncated):
        return run_parsed("thermal_eval.evaluate.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
