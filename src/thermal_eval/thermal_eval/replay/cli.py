"""``thermal-comp replay REC --model talc|agp|cd [--config YAML] [--set key=value ...] --json OUT``
``[--errors-topic TOPIC] [--temperatures-topic TOPIC] [--score-from-h H]``

The virtual experiment of the Blaser thesis §6.3: replay a recording (the twin's CSV, a bag
folder or an ``.mcap`` file) through an adaptive model, without ROS, probing only when the
model asks, with realistic probe noise (Table 5.4: 0.25 um linear, 1.2 um/m angular, 0.25 um
resolution). Prints a Table 6.5-style table, writes the indicators as JSON and a PNG of true
error, compensation and residual per component. A model component is named as its error column
(``z_um``) or without its ``_um``; ``--score-from-h`` scores a held-out window only. An existing
output is refused (exit code 3) unless ``--force``.
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.probe_and_hold import (TABLE_5_4_NOISE_ANGULAR_UM_PER_M, TABLE_5_4_NOISE_LINEAR_UM,
                                                TABLE_5_4_RESOLUTION_UM)
from thermal_comp_common.bags.truncation import add_allow_truncated_argument, truncated_bags_allowed
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed

MODEL_KINDS = ("talc", "agp", "cd")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", metavar="REC", nargs="+",
                    help="twin CSV, bag folder or .mcap file; several, a folder, a glob or a manifest: every run "
                         "alone (OUT.<run>.json) and pooled (OUT)")
    ap.add_argument("--model", required=True, choices=MODEL_KINDS, help="model kind")
    ap.add_argument("--config", metavar="YAML",
                    help="model parameters (a mapping; `preset:` for TALC); `sensors` and `components` for every "
                         "model (components default to the recording's error columns)")
    ap.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                    help="override one parameter (YAML value, e.g. post_cp_interval_h=inf); repeatable")
    ap.add_argument("--json", metavar="OUT", required=True, help="write the indicators to this JSON file")
    ap.add_argument("--png", metavar="OUT", help="plot (default: the JSON path with .png)")
    ap.add_argument("--force", action="store_true", help="overwrite an existing --json / --png (refused otherwise)")
    ap.add_argument("--probe-noise-um", type=float, default=TABLE_5_4_NOISE_LINEAR_UM,
                    help="probe noise sigma on linear components, um (default %(default)s, Table 5.4)")
    ap.add_argument("--probe-noise-um-per-m", type=float, default=TABLE_5_4_NOISE_ANGULAR_UM_PER_M,
                    help="probe noise sigma on angular components, um/m (default %(default)s, Table 5.4)")
    ap.add_argument("--probe-resolution-um", type=float, default=TABLE_5_4_RESOLUTION_UM,
                    help="quantisation of probe readings (default %(default)s; 0 = none)")
    ap.add_argument("--seed", type=int, default=0, help="probe-noise seed (default %(default)s)")
    ap.add_argument("--hours", type=float, default=None, help="replay only the first HOURS of the recording")
    ap.add_argument("--errors-topic", default="errors/ground_truth", metavar="TOPIC",
                    help="bag topic of the measured errors (default %(default)s; `import-csv --errors measured` "
                         "writes errors/measured)")
    ap.add_argument("--temperatures-topic", default="temperatures", metavar="TOPIC",
                    help="bag topic of the temperatures (default %(default)s)")
    ap.add_argument("--score-from-h", type=float, default=None, metavar="H",
                    help="score only the rows from H hours after the first row (a held-out window; "
                         "default: the whole compensation part)")
    ap.add_argument("--prior", metavar="PRIOR", help="start the model (talc, agp or cd) from this prior of its kind (thermal-comp prior --model KIND, or --from-state of another machine); its model_kind must match --model")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_sample_period_argument(ap)
    add_allow_truncated_argument(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    with truncated_bags_allowed(args.allow_truncated):
        return run_parsed("thermal_eval.replay.command:run", args)


if __name__ == "__main__":
    sys.exit(main())
