"""``thermal-comp demo``: a compensated machine cell end to end on the built-in twin (no hardware).

Starts the whole graph as separate ROS 2 processes under the launcher in its own ROS_DOMAIN_ID
(``demo_graph``), then writes the bag, an .rrd, ``summary.json`` and a PNG and prints the table
of uncompensated versus compensated P99 beside the thesis's (``demo_summary``, ``demo_plot``).
The graph and the evaluation are described in README.md ("What the demo does").
"""
from __future__ import annotations

import argparse
import pathlib
import sys

from thermal_comp.demo.cell import BUILD_PRIOR, DEFAULT_PRIOR, MACHINES, DemoConfig
from thermal_comp_common.command_line import run_parsed


def _unit(text: str) -> int | None:
    if text == "nominal":
        return None
    try:
        v = int(text)
    except ValueError:
        v = -1
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not 'nominal' or an integer >= 0")
    return v


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp demo", description="Run a compensated machine cell end to end on the built-in twin (no hardware needed).")
    ap.add_argument("--machine", default="nmv5000", choices=sorted(MACHINES), help="built-in twin preset")
    ap.add_argument("--scenario", help="twin scenario (default: talc-178h-dry for nmv5000, "
                                       "lathe-random-speed for swiss-lathe)")
    ap.add_argument("--hours", type=float, help="shorten the scenario to this many simulated hours")
    ap.add_argument("--seed", type=int, default=0, help="seed of the scenario and the sensor noise")
    ap.add_argument("--step", type=float, dest="step_s",
                    help="simulation step in s (default 300 s on nmv5000, the thesis's 5-min grid)")
    ap.add_argument("--out", default="demo_out", help="output folder (bag, demo.rrd, summary.json, PNG, logs)")
    ap.add_argument("--view", choices=("auto", "live", "rrd", "none"), default="auto",
                    help="auto: live rerun viewer when a display exists, else an .rrd file (always written)")
    ap.add_argument("--cnc", choices=("opcua", "twin"), default="opcua",
                    help="opcua: the bridge writes to the CNC emulator over OPC UA (default); twin: directly")
    ap.add_argument("--unit", type=_unit, default=1,
                    help="the plant: unit N of the machine type (its parameters perturbed within the "
                         "tolerances of thermal_twin.machine.instance, seed N) or 'nominal' (default 1)")
    ap.add_argument("--plant", metavar="FILE",
                    help="the plant from a machine YAML file of the --machine type (e.g. a unit that differs "
                         "structurally: config/plants/); replaces --unit")
    ap.add_argument("--learn-every-h", type=_positive_or_zero, default=0.0, metavar="H",
                    help="run the online learner in the graph: `thermal-comp learn` on the cell's recording "
                         "every H simulated hours, its prior adopted only if learn's held-out test says so "
                         "(docs/learn.md, \"Online learning\"); 0 = no learner (default)")
    prior = ap.add_mutually_exclusive_group()
    prior.add_argument("--prior", nargs="?", const=BUILD_PRIOR, default=DEFAULT_PRIOR, metavar="PRIOR",
                       help="start the model (TALC on nmv5000, AGP on swiss-lathe) from a prior of the machine "
                            "type: a file from `thermal-comp prior`, or without a file (the default) the nominal "
                            "type's prior, cached (built once: TALC about 20 s, AGP a few minutes); the default "
                            "run has none where no prior applies and says why")
    prior.add_argument("--no-prior", dest="prior", action="store_const", const=None,
                       help="start from zero, the thesis's protocol (calibration phase, order growth)")
    ap.add_argument("--compare-no-prior", action="store_true",
                    help="also run the same plant without the prior (into OUT/no_prior) and print both")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--wall-timeout", type=float, default=3600.0, help="give up after this many wall seconds")
    ap.add_argument("--real-time-factor", type=_positive_or_zero, default=0.0, metavar="X",
                    help="at most X simulated s per wall s, to watch the cell live (default 0: as fast as "
                         "the graph goes)")
    return ap


def _positive_or_zero(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not (v >= 0.0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r} is not a number >= 0")
    return v


def main(argv: list[str] | None = None) -> int:
    """Run a compensated machine cell end to end on the built-in twin (no hardware)."""
    a = _parser().parse_args(argv)
    cfg = DemoConfig(machine=a.machine, scenario=a.scenario, hours=a.hours, seed=a.seed, step_s=a.step_s,
                     out_dir=pathlib.Path(a.out), view=a.view, cnc=a.cnc, progress=not a.no_progress,
                     wall_timeout_s=a.wall_timeout, unit=a.unit, prior=a.prior,
                     real_time_factor=a.real_time_factor, plant=a.plant, learn_every_h=a.learn_every_h)
    if a.compare_no_prior and a.prior is None:
        print("thermal-comp demo: --compare-no-prior compares against the prior; it cannot go with --no-prior",
              file=sys.stderr)
        return 1
    return run_parsed("thermal_comp.demo.run:run", cfg, a.compare_no_prior)


if __name__ == "__main__":
    sys.exit(main())
