"""``thermal-comp sweep REC --out DIR [--jobs N] [--engine dask --address tcp://HOST:8786] [--limit N] ...``

TALC over the Blaser thesis's Table 6.1 grid (2,191 combinations per load case, see
``thermal_eval.sweep.grid``) on one recording, in parallel with a progress bar: on a local process
pool (default) or on a Dask cluster (``--engine dask``; docs/distributed.md). Writes
``DIR/results.jsonl`` (one line per combination; rerun the same command to resume),
``DIR/table.csv`` (sorted by P99_lin; probe-and-hold at each row's Q_prod beside it), ``DIR/best.json`` (lowest P99_lin with Q_prod >= 95 %)
and the plots ``DIR/p99_vs_qprod.png`` (Fig. 6.9) and ``DIR/qprod_vs_p99_limit.png`` (Fig. 6.10).
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.runtime.engine_options import add_engine_arguments
from thermal_comp_common.metrics import Q_PROD_MIN_PCT
from thermal_comp_common.probe_and_hold import (TABLE_5_4_NOISE_ANGULAR_UM_PER_M, TABLE_5_4_NOISE_LINEAR_UM,
                                                TABLE_5_4_RESOLUTION_UM)
from thermal_comp_common.bags.truncation import add_allow_truncated_argument
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp sweep", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", metavar="REC", help="twin CSV, bag folder or .mcap file (one load case)")
    ap.add_argument("--out", required=True, metavar="DIR", help="folder for results.jsonl, table, plots")
    add_engine_arguments(ap, what="replays")
    ap.add_argument("--limit", type=int, default=None, help="only N combinations, spread evenly over the grid")
    ap.add_argument("--grid-subset", default="", metavar="SPEC",
                    help="restrict the grid, e.g. 'cp_length_h=8.5,12;post_cp_interval_h=2,10'; "
                         "update_interval_h=8,24 sweeps that parameter too")
    ap.add_argument("--update-interval-h", type=float, default=24.0,
                    help="update interval held for the grid (default %(default)s h, Table 6.4)")
    ap.add_argument("--config", metavar="YAML", help="base TALC parameters (the grid's five override them)")
    ap.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                    help="override one base parameter; repeatable")
    ap.add_argument("--q-prod-min", type=float, default=Q_PROD_MIN_PCT, help="Q_prod constraint, %% (default 95)")
    ap.add_argument("--probe-noise-um", type=float, default=TABLE_5_4_NOISE_LINEAR_UM)
    ap.add_argument("--probe-noise-um-per-m", type=float, default=TABLE_5_4_NOISE_ANGULAR_UM_PER_M)
    ap.add_argument("--probe-resolution-um", type=float, default=TABLE_5_4_RESOLUTION_UM)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-progress", action="store_true")
    add_allow_truncated_argument(ap)
    add_sample_period_argument(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_parsed("thermal_eval.sweep.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
