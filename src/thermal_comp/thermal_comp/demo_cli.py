"""``thermal-comp demo``: a compensated machine cell end to end on the built-in twin (no hardware).

Starts the whole graph as separate ROS 2 processes under the launcher in its own ROS_DOMAIN_ID
(``demo_graph``), then writes the bag, an .rrd, ``summary.json`` and a PNG and prints the table
of uncompensated versus compensated P99 beside the thesis's (``demo_summary``, ``demo_plot``).
The graph and the evaluation are described in README.md ("What the demo does").
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
from typing import Any

from thermal_comp.demo_cell import MACHINES, DemoConfig, DemoError
from thermal_comp.demo_graph import run_graph
from thermal_comp.demo_plot import plot, write_rrd
from thermal_comp.demo_series import read_series
from thermal_comp.demo_summary import print_table, summarise


def run_demo(cfg: DemoConfig) -> dict[str, Any]:
    """Run the graph, then write summary.json, the PNG and the .rrd; return the summary."""
    if cfg.machine not in MACHINES:
        raise DemoError(f"--machine: {cfg.machine!r} is not one of {sorted(MACHINES)}")
    cfg.scenario = cfg.scenario or MACHINES[cfg.machine]["scenario"]
    if cfg.prior == BUILD_PRIOR:
        cfg.prior = str(_build_prior(cfg))
    record = run_graph(cfg)
    out = cfg.out_dir.resolve()
    series = read_series(out / "bag")
    summary = summarise(series, cfg, record)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot(series, summary, out / "compensation.png")
    write_rrd(out / "bag", out / "demo.rrd")
    return summary


#: ``--prior`` without a file: build the machine type's prior into the output folder first
BUILD_PRIOR = "build"


def _build_prior(cfg: DemoConfig) -> pathlib.Path:
    """The nominal type's TALC prior (thermal-comp prior's defaults) in the output folder."""
    import yaml
    from talc_model.prior import save_prior
    from thermal_comp.prior_cli import build_prior, default_config_path, TRAINING_SCENARIOS
    if MACHINES[cfg.machine]["model_kind"] != "talc" or cfg.machine not in TRAINING_SCENARIOS:
        raise DemoError(f"--prior: no prior for machine {cfg.machine!r} (TALC machines: {sorted(TRAINING_SCENARIOS)})")
    if cfg.scenario in TRAINING_SCENARIOS[cfg.machine]:
        raise DemoError(f"--prior: the scenario {cfg.scenario!r} is one of the prior's training programmes; "
                        "give a prior file built without it")
    config = yaml.safe_load(default_config_path(cfg.machine).read_text())
    print(f"building the prior of the machine type {cfg.machine} (nominal twin, "
          f"{', '.join(TRAINING_SCENARIOS[cfg.machine])})", flush=True)
    prior = build_prior(cfg.machine, config, TRAINING_SCENARIOS[cfg.machine])
    return save_prior(cfg.out_dir.resolve() / "prior.json", prior)


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
                         "tolerances of thermal_twin.machine_instance, seed N) or 'nominal' (default 1)")
    ap.add_argument("--prior", nargs="?", const=BUILD_PRIOR, default=None, metavar="PRIOR",
                    help="start TALC from a prior of the machine type (a file from `thermal-comp prior`; "
                         "without a file: build it first from the nominal twin, about 20 s)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--wall-timeout", type=float, default=3600.0, help="give up after this many wall seconds")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run a compensated machine cell end to end on the built-in twin (no hardware)."""
    a = _parser().parse_args(argv)
    cfg = DemoConfig(machine=a.machine, scenario=a.scenario, hours=a.hours, seed=a.seed, step_s=a.step_s,
                     out_dir=pathlib.Path(a.out), view=a.view, cnc=a.cnc, progress=not a.no_progress,
                     wall_timeout_s=a.wall_timeout, unit=a.unit, prior=a.prior)
    try:
        summary = run_demo(cfg)
    except (DemoError, ValueError) as exc:
        print(f"thermal-comp demo: {exc}", file=sys.stderr)
        return 1
    print_table(summary)
    out = cfg.out_dir.resolve()
    print(f"written: {out / 'summary.json'}, {out / 'compensation.png'}, {out / 'demo.rrd'}, {out / 'bag'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
