"""``thermal-comp prior --machine M [--model talc|agp|cd] --out PRIOR``: a prior from the machine TYPE or its history.

Simulates the nominal twin of ``M`` on training load programmes (never the run a prior is later
used on: other scenarios and seeds) and fits the prior of the model (TALC: talc_model.prior.talc,
AGP: talc_model.prior.agp, characteristic diagrams: talc_model.prior.cd); or, with ``--from-state``, turns the
persisted TALC, AGP or CD model of another machine into a prior; or, with ``--from-recordings``,
fits it on the machine's own past runs (talc_model.prior.history). On a real machine this costs
no probing: it is simulation or history. docs/prior.md.
"""
from __future__ import annotations

import argparse
import sys

from thermal_comp.prior.programmes import SEED_BASE, TRAINING_SCENARIOS
from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp prior", description=__doc__.split("\n\n")[0])
    ap.add_argument("--machine", default=None,
                    help="the NOMINAL machine type (preset name or YAML; default nmv5000); with --from-recordings "
                         "the machine's name written into the prior (default: history)")
    ap.add_argument("--out", required=True, help="prior file to write (JSON)")
    ap.add_argument("--model", choices=sorted(TRAINING_SCENARIOS),
                    help="the model the prior is for (default: the one the demo runs on the machine: "
                         "TALC on nmv5000, AGP on swiss-lathe)")
    ap.add_argument("--config", help="model configuration YAML (default: the one the demo runs the machine with)")
    ap.add_argument("--scenarios", help="comma-separated training scenarios, the last held out (default: "
                    + "; ".join(f"{k} {m}: {','.join(v)}" for k, d in TRAINING_SCENARIOS.items() for m, v in d.items())
                    + ")")
    ap.add_argument("--seed-base", type=int, default=SEED_BASE, help="seed of the first training run (default %(default)s)")
    ap.add_argument("--na-max", type=int, default=1, help="TALC: largest n_a of the prior (default %(default)s)")
    ap.add_argument("--nb-max", type=int, default=8, help="TALC: largest n_b of the prior (default %(default)s)")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--from-state", metavar="STATE",
                     help="instead: the persisted TALC, AGP or CD model state (model_state.json) of another machine")
    src.add_argument("--from-recordings", metavar="RUNS",
                     help="instead: the machine's past runs, comma-separated CSV files, bag folders / .mcap files, "
                          "folders of them or globs, in time order (the last one is held out to choose and check "
                          "the prior); --model picks the model (default talc), --config overrides the "
                          "configuration taken from the recordings' columns")
    add_sample_period_argument(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.sample_period_s is not None and not args.from_recordings:
        ap.error(f"--sample-period-s {args.sample_period_s:g}: only with --from-recordings (the runs it reads)")
    return run_parsed("thermal_comp.prior.build:run", args)

if __name__ == "__main__":
    sys.exit(main())
