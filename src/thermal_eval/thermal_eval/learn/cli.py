"""Learn a unit's twin from its cell's recording: ``thermal-comp learn REC --twin M --out DIR``.

From what a cell records (temperatures, machine inputs, the probing results and the offsets
the bridge held; never the ground-truth topic): the twin calibrated on the probes of the first
``--train-h`` hours but the last ``--validate-h`` (``DIR/unit_twin.yaml``), adopted only if it is
better on those validation probes, a prior built on an adopted twin whose soft sensors are that
twin (``DIR/prior.json`` with ``DIR/model_config.yaml``), and a report (``report.md``,
``report.json``): what moved and by how much, the held-out probes before and after, the type's
and the unit's prior replayed over the recording's probes, beside holding the last probe, the
training mean and a static regression. The adaptive test is against the type's prior, or with
``--current-prior`` against the prior running now (online learning); the report names it.
Several recordings of one unit (``learn A B C``, a folder, a glob or a manifest): the twin is
calibrated on the training runs jointly, adopted on the validation runs, scored per held-out run
and pooled (``--runs-split``, learn.runs). docs/learn.md.
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.bags.truncation import add_allow_truncated_argument, truncated_bags_allowed
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed
from thermal_comp_common.run_splits import DEFAULT_RUN_SPLIT


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp learn", description=__doc__.split("\n\n")[0])
    p.add_argument("recording", metavar="REC", nargs="+",
                   help="the cell's bag (folder or .mcap) or a recording CSV whose error columns hold probe results "
                        "(total error since the run's start), empty elsewhere; several: files, a folder, a glob or a "
                        "manifest (path, unit, programme, date, hall_setpoint_c), runs of one unit")
    p.add_argument("--runs-split", default=None, metavar="HOW",
                   help="several runs: which train, validate and test (evaluate's grammar: TRAIN,VAL,TEST fractions, "
                        f"default {DEFAULT_RUN_SPLIT}; test=NAME,...[;validation=NAME,...]; by:FIELD=VALUE); one fold")
    p.add_argument("--twin", required=True, help="the type's twin: machine YAML file or preset name")
    p.add_argument("--out", required=True, help="output folder (new or empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty --out")
    p.add_argument("--train-h", type=float, default=None,
                   help="one recording: learn from the probes of the first H hours; later ones are held out "
                        "(default 48)")
    p.add_argument("--validate-h", type=float, default=None,
                   help="the last H hours of the --train-h window (several runs without validation runs: of every "
                        "training run) only decide whether the learned twin is adopted (not fitted on; default a "
                        "quarter)")
    p.add_argument("--max-nfev", type=int, default=20, help="at most this many optimiser iterations (default 20)")
    p.add_argument("--probe-noise-um", type=float, default=None,
                   help="the probes' standard uncertainty for linear components (default: Table 5.4, 0.25)")
    p.add_argument("--probe-noise-um-per-m", type=float, default=None,
                   help="the same for angular components (default: Table 5.4, 1.2)")
    p.add_argument("--no-prior", action="store_true", help="only the unit twin and its held-out scores")
    p.add_argument("--current-prior", metavar="PRIOR.json", default=None,
                   help="test the learned prior's adaptive model against this prior (the one running now; its "
                        "soft-sensor twin must be --twin) instead of the type's prior")
    p.add_argument("--current-config", metavar="CFG.yaml", default=None,
                   help="the model configuration --current-prior runs with (default: the shipped one for its "
                        "soft-sensor twin)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_sample_period_argument(p)
    add_allow_truncated_argument(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with truncated_bags_allowed(args.allow_truncated):
        return run_parsed("thermal_eval.learn.run:run", args)


if __name__ == "__main__":
    sys.exit(main())
