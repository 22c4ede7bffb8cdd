"""The work of ``thermal-comp demo`` (:mod:`thermal_comp.demo.cli` parses the arguments): run the
graph (``demo_graph``), resolve the machine type's prior, write summary.json, the PNG and the .rrd
and print the table (``demo_summary``, ``demo_plot``).
"""
from __future__ import annotations

import dataclasses
import json
import pathlib
import shutil
import sys
from typing import Any

from thermal_comp.demo.cell import (BUILD_PRIOR, DEFAULT_PRIOR, LEARNING_REAL_TIME_FACTOR, MACHINES, DemoConfig,
                                    DemoError)
from thermal_comp.demo.graph import run_graph
from thermal_comp.demo.learning import learning_summary, print_learning
from thermal_comp.demo.plot import plot, write_rrd
from thermal_comp.demo.series import read_series
from thermal_comp.demo.summary import compensation_in_effect, print_prior_gain, print_table, summarise
from thermal_twin.machine.schema import MachineSpecError, load_machine
from thermal_comp.prior.build import cached_prior, default_config, training_scenarios
from thermal_comp.prior.programmes import TRAINING_SCENARIOS


def run_demo(cfg: DemoConfig, compare_no_prior: bool = False) -> dict[str, Any]:
    """Run the graph, then write summary.json, the PNG and the .rrd; return the summary.
    ``cfg.prior`` = DEFAULT_PRIOR: the machine type's cached prior where one applies;
    ``compare_no_prior``: run the same plant again without the prior (into ``out/no_prior``)."""
    if cfg.machine not in MACHINES:
        raise DemoError(f"--machine: {cfg.machine!r} is not one of {sorted(MACHINES)}")
    cfg.scenario = cfg.scenario or MACHINES[cfg.machine]["scenario"]
    check_plant(cfg)
    if cfg.learn_every_h > 0 and not cfg.real_time_factor:
        cfg.real_time_factor = LEARNING_REAL_TIME_FACTOR
        print(f"online learning every {cfg.learn_every_h:g} h: the graph runs at most {cfg.real_time_factor:g} x "
              "real time (--real-time-factor), so that a learning of seconds of wall time spans hours, not days, "
              "of simulated time", flush=True)
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
    if cfg.learn_every_h > 0:
        summary["learning"] = learning_summary(series, compensation_in_effect(series), summary["q_prod_pct"],
                                               out, cfg.seed)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot(series, summary, out / "compensation.png")
    write_rrd(out / "bag", out / "demo.rrd")
    return summary


def check_plant(cfg: DemoConfig) -> None:
    """A plant file must be a valid machine of the demo's type (its scenarios are keyed by it)."""
    if not cfg.plant:
        return
    try:
        plant = load_machine(cfg.plant)
    except (MachineSpecError, OSError, ValueError) as exc:
        raise DemoError(f"--plant {cfg.plant}: {exc}") from None
    if plant.name != cfg.machine:
        raise DemoError(f"--plant {cfg.plant}: a machine of type {plant.name!r}, the demo runs {cfg.machine!r} "
                        "(--machine)")


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


def run(cfg: DemoConfig, compare_no_prior: bool) -> int:
    """Run the demo of ``cfg`` and print its table(s); the exit code (0 done, 1 the demo failed)."""
    try:
        summary = run_demo(cfg, compare_no_prior=compare_no_prior)
    except (DemoError, ValueError) as exc:
        print(f"thermal-comp demo: {exc}", file=sys.stderr)
        return 1
    print_table(summary)
    print_learning(summary)
    if summary.get("no_prior"):
        print_table(summary["no_prior"])
        print_prior_gain(summary, summary["no_prior"])
    out = cfg.out_dir.resolve()
    print(f"written: {out / 'summary.json'}, {out / 'compensation.png'}, {out / 'demo.rrd'}, {out / 'bag'}")
    return 0
