"""Find what physics the twin lacks: compare it with a recording, locate, name, model, prove.

``thermal-comp diagnose --twin MACHINE.yaml --recording REC --out DIR`` (REC: a recording
CSV or a rosbag2 MCAP bag) simulates the
twin with the recording's inputs, locates and diagnoses the residuals, fits the effect
library on a training window, adopts what improves the held-out window, and writes
``DIR/report.json``, ``DIR/report.md`` (PNG plots beside it), ``DIR/diagnosis.rrd`` (rerun)
and, when an effect is adopted, ``DIR/twin_augmented.yaml``. With ``--calibrate`` the twin's
existing parameters are fitted first (``DIR/twin_calibrated.yaml``; the report separates
mis-calibrated parameters from missing mechanisms); physics outside the vocabulary is
answered ``unnamed`` with a sparse formula. The independent tasks (channel analyses, candidate
screening and fits, out-of-vocabulary fits) run on a local process pool of ``--jobs`` processes
(default: the cores) or a Dask cluster (``--engine dask [--address tcp://HOST:8786]``); the
answer is the same on every engine (docs/distributed.md).
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.runtime.engine_options import add_engine_arguments
from thermal_twin.diagnose.effects import EFFECTS
from thermal_comp_common.bags.truncation import add_allow_truncated_argument, truncated_bags_allowed
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp diagnose", description=__doc__.split("\n\n")[0])
    p.add_argument("--twin", required=True, help="machine YAML file or preset name (e.g. spindle-stand)")
    p.add_argument("--recording", required=True,
                   help="recording CSV in the twin's CSV format (time_s, inputs, <sensor>_c, error "
                        "channels), or a rosbag2 MCAP bag (folder or .mcap file)")
    p.add_argument("--map", action="append", default=[], metavar="OLD=NEW|NAME*FACTOR",
                   help="rename a recording column to the twin's name, or scale one (e.g. ch3_um*-1 "
                        "flips its sign); repeatable")
    p.add_argument("--map-file", help="YAML column mapping {columns: {old: new}, scale: {name: factor}}")
    p.add_argument("--temperatures-topic", default="temperatures",
                   help="bag only: TemperatureArray topic of the sensor readings (default temperatures)")
    p.add_argument("--errors-topic", default="errors/ground_truth",
                   help="bag only: ThermalErrors topic of the error channels (default errors/ground_truth; "
                        "errors/measured for probed errors)")
    p.add_argument("--out", required=True, help="output directory (must be new or empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty --out")
    p.add_argument("--holdout-fraction", type=float, default=1 / 3,
                   help="last fraction of the recording kept out of every fit (default 1/3)")
    p.add_argument("--max-effects", type=int, default=2, help="at most this many effects adopted (default 2)")
    p.add_argument("--min-improvement", type=float, default=5.0,
                   help="held-out improvement in %% an effect needs to be adopted (default 5)")
    p.add_argument("--effects", default=",".join(e for e in EFFECTS if e != "none"),
                   help="comma-separated subset of the effect vocabulary to try")
    p.add_argument("--start-hour", type=float, default=0.0,
                   help="clock hour at time_s = 0, for the day/night regimes (default 0)")
    p.add_argument("--max-lag-h", type=float, default=6.0, help="cross-correlation lags up to this (h)")
    p.add_argument("--calibrate", action="store_true",
                   help="fit the twin's existing parameters first; effects must beat that on held-out data")
    p.add_argument("--bounds", help="with --calibrate: YAML calibration section (kinds, parameters)")
    p.add_argument("--max-nfev", type=int, default=20, help="with --calibrate: optimiser iterations (default 20)")
    p.add_argument("--no-unnamed", action="store_true", help="do not fit an out-of-vocabulary discrepancy")
    p.add_argument("--no-clock-offset", action="store_true",
                   help="do not look for a common time shift of the measured channels against the inputs")
    p.add_argument("--no-rerun", action="store_true", help="do not write the rerun recording")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_sample_period_argument(p)
    add_allow_truncated_argument(p)
    add_engine_arguments(p, what="channel analyses and candidate fits")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with truncated_bags_allowed(args.allow_truncated):
        return run_parsed("thermal_twin.diagnose.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
