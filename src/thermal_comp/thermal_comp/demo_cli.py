"""``thermal-comp demo``: a compensated machine cell end to end on the built-in twin (no hardware).

Starts the whole graph as separate ROS 2 processes under the launcher in its own ROS_DOMAIN_ID
(``demo_graph``), then writes the bag, an .rrd, ``summary.json`` and a PNG and prints the table
of uncompensated versus compensated P99 beside the thesis's (``demo_summary``, ``demo_plot``).
The graph and the evaluation are described in README.md ("What the demo does").
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
from typing import Any

from thermal_comp.demo_cell import MACHINES, DemoConfig, DemoError
from thermal_comp.demo_graph import run_graph
from thermal_comp.demo_plot import plot, write_rrd
from thermal_comp.demo_series import read_series
from thermal_comp.demo_summary import print_prior_gain, print_table, summarise


def run_demo(cfg: DemoConfig, compare_no_prior: bool = False) -> dict[str, Any]:
    """Run the graph, then write summary.json, the PNG and the .rrd; return the summary.
    ``cfg.prior`` = DEFAULT_PRIOR: the machine type's cached prior where one applies;
    ``compare_no_prior``: run the same plant again without the prior (into ``out/no_prior``)."""
    if cfg.machine not in MACHINES:
        raise DemoError(f"--machine: {cfg.machine!r} is not one of {sorted(MACHINES)}")
    cfg.scenario = cfg.scenario or MACHINES[cfg.machine]["scenario"]
    note = resolve_prior(cfg)
    summary = _run_and_summarise(cfg)
    if note:
        summary["prior_note"] = note
    if compare_no_prior and cfg.prior:
        base = dataclasses.replace(cfg, prior=None, out_dir=cfg.out_dir / "no_prior", view="none")
        print(f"the same plant without the prior (the thesis's protocol), into {base.out_dir}", flush=True)
        summary["no_prior"] = _run_and_summarise(base)
    out = cfg.out_dir.resolve()
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def _run_and_summarise(cfg: DemoConfig) -> dict[str, Any]:
    """One run of the graph into ``cfg.out_dir``: summary.json, the PNG and the .rrd."""
    record = run_graph(cfg)
    out = cfg.out_dir.resolve()
    series = read_series(out / "bag")
    summary = summarise(series, cfg, record)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot(series, summary, out / "compensation.png")
    write_rrd(out / "bag", out / "demo.rrd")
    return summary


#: ``--prior`` without a file: the machine type's prior (from the cache, built on a miss)
BUILD_PRIOR = "build"
#: no ``--prior`` / ``--no-prior``: the type's prior where one applies, else none (said why)
DEFAULT_PRIOR = "default"


def resolve_prior(cfg: DemoConfig) -> str | None:
    """Turn ``cfg.prior`` DEFAULT_PRIOR / BUILD_PRIOR into a prior file (cached or built, copied
    into the run's folder) or None; returns why the default has none (None: it has one or
    ``cfg.prior`` was a file or None already). ``cfg.scenario`` must be set."""
    note = None
    if cfg.prior == DEFAULT_PRIOR:
        note = _no_default_prior_reason(cfg)
        cfg.prior = None if note else BUILD_PRIOR
        if note:
            print(f"no prior: {note}", flush=True)
    if cfg.prior == BUILD_PRIOR:
        cfg.prior = str(_build_prior(cfg))
    return note


def _no_default_prior_reason(cfg: DemoConfig) -> str | None:
    """Why the default run has no prior (None: it has one)."""
    from thermal_comp.prior_cli import TRAINING_SCENARIOS, training_scenarios
    kind = MACHINES[cfg.machine]["model_kind"]
    scenarios = training_scenarios(kind, cfg.machine)
    if not scenarios:
        with_prior = sorted(m for m, spec in MACHINES.items() if training_scenarios(spec["model_kind"], m))
        return (f"machine {cfg.machine!r} runs {kind.upper()}, which has no prior of the type yet "
                f"(priors: {', '.join(f'{k} {sorted(d)}' for k, d in TRAINING_SCENARIOS.items())}; "
                f"demo machines with one: {with_prior})")
    if cfg.scenario in scenarios:
        return (f"the scenario {cfg.scenario!r} is one of the prior's training programmes (a prior never "
                "sees the evaluated run); give --prior FILE built without it")
    return None


def _build_prior(cfg: DemoConfig) -> pathlib.Path:
    """The nominal type's prior of the machine's model (TALC on nmv5000, AGP on swiss-lathe;
    thermal-comp prior's defaults), from the cache or built on a miss (TALC about 20 s, AGP a
    few minutes), copied into the output folder so the run's folder is complete."""
    import shutil

    from thermal_comp.prior_cli import cached_prior, default_config, training_scenarios
    reason = _no_default_prior_reason(cfg)
    if reason:
        raise DemoError(f"--prior: {reason}")
    kind = MACHINES[cfg.machine]["model_kind"]
    scenarios = training_scenarios(kind, cfg.machine)
    print(f"{kind.upper()} prior of the machine type {cfg.machine} (nominal twin, {', '.join(scenarios)}): "
          "from the cache, or built now ...", flush=True)
    path, built = cached_prior(cfg.machine, default_config(cfg.machine, kind), scenarios, kind=kind)
    print(f"{'built' if built else 'cached'} {kind.upper()} prior of the machine type {cfg.machine}: {path}",
          flush=True)
    out = cfg.out_dir.resolve()
    out.mkdir(parents=True, exist_ok=True)
    return pathlib.Path(shutil.copyfile(path, out / "prior.json"))


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
                     real_time_factor=a.real_time_factor)
    if a.compare_no_prior and a.prior is None:
        print("thermal-comp demo: --compare-no-prior compares against the prior; it cannot go with --no-prior",
              file=sys.stderr)
        return 1
    try:
        summary = run_demo(cfg, compare_no_prior=a.compare_no_prior)
    except (DemoError, ValueError) as exc:
        print(f"thermal-comp demo: {exc}", file=sys.stderr)
        return 1
    print_table(summary)
    if summary.get("no_prior"):
        print_table(summary["no_prior"])
        print_prior_gain(summary, summary["no_prior"])
    out = cfg.out_dir.resolve()
    print(f"written: {out / 'summary.json'}, {out / 'compensation.png'}, {out / 'demo.rrd'}, {out / 'bag'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
