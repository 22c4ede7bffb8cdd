"""TALC with the machine type's prior on every load case, beside probe-and-hold.

``python -m thermal_eval.replay.prior_cases [--case C ...] [--set key=value ...] [--json OUT]`` replays
each case on **unit #1** (seed 0 unless ``--seed``, Table 5.4 probe noise and resolution) with
TALC started from a prior of the NOMINAL type, built from the training programmes of ``thermal-comp prior``
(prior_programmes.TRAINING_SCENARIOS, seeds 101, 102, ...) without the evaluated programme; the demo's
talc-178h-dry is in none of them, so its prior is the demo's. Every result is printed beside
probe-and-hold at the model's own Q_prod (ratio = P99_lin / probe-and-hold's; goal <= 0.5). The
tables of docs/talc.md (sections "Selection consistent with the loop, ..." on) are its output.
With the shipped configuration the prior and TALC run on the machine type's soft sensors
(``type_input_names``, docs/talc.md, "The machine type's physics as TALC's inputs"); ``--set type_input_names=[]`` gives the
thesis's inputs and the MWF flag.
``--change-goal 0.5`` turns on the change-probing rule with thresholds derived from each prior's
held-out training programme (talc_model.probing.change_threshold; docs/talc.md, "The probing threshold from the prior's own virtual experiment").
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
from typing import Any, Mapping, Sequence

import numpy as np

from thermal_comp.prior.programmes import SEED_BASE, TRAINING_SCENARIOS
from thermal_twin.machine.instance import machine_instance
from thermal_twin.sim.scenarios import make_timeline, scenario_names
from thermal_twin.sim.simulate import simulate

from thermal_eval.replay.baseline_beside import beside_probe_and_hold
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM, ReplayInputError, parse_overrides, probe_noise
from thermal_eval.replay.virtual_experiment import run_virtual_experiment

CASES = ["load-case-A", "load-case-B", "load-case-C", "load-case-D", "talc-178h-dry", "talc-144h-mwf"]
PLANT_UNIT = 1
RUN_SEED = 0


def shipped_config() -> dict[str, Any]:
    """The demo's TALC configuration (talc_nmv5000.yaml)."""
    from thermal_comp.prior.build import default_config  # heavy: scipy.signal only when a prior is built
    return default_config("nmv5000", "talc")


def prior_training(case: str, programmes: Sequence[str] | None = None) -> list[tuple[str, int]]:
    """(programme, seed) of the prior for ``case``: the training programmes (default: those of
    ``thermal-comp prior``; the last is held out to choose the orders) without it."""
    names = [s for s in (programmes or TRAINING_SCENARIOS["talc"]["nmv5000"]) if s != case]
    return [(s, SEED_BASE + i) for i, s in enumerate(names)]


def _simulate(machine, scenario: str, seed: int, cache: dict):
    key = ("nominal" if isinstance(machine, str) else f"unit {PLANT_UNIT}", scenario, seed)
    if key not in cache:
        cache[key] = simulate(machine, make_timeline("nmv5000", scenario, seed=seed), seed=seed).to_recording()
    return cache[key]


def error_location(result, components: Sequence[str], top: int = 5) -> list[dict[str, Any]]:
    """Where the largest residuals sit: per component the hours of its ``top`` largest |residual|
    (rows at least an hour apart), with the phase there."""
    t_h = np.asarray(result.time_s, float) / 3600.0
    out = []
    for c in components:
        r = np.abs(np.asarray(result.residual[c], float))
        order = np.argsort(-np.where(np.isfinite(r), r, -1.0))
        picked: list[int] = []
        for i in order:
            if all(abs(t_h[i] - t_h[j]) >= 1.0 for j in picked):
                picked.append(int(i))
            if len(picked) >= top:
                break
        out.append({"component": c, "peaks": [(round(float(t_h[i]), 1), round(float(r[i]), 2), result.phase[i])
                                              for i in picked]})
    return out


def run_case(case: str, config: Mapping[str, Any], cache: dict | None = None,
             prior_overrides: Mapping[str, Any] | None = None, seed: int = RUN_SEED,
             training: Sequence[str] | None = None, change_goal: float | None = None,
             change_from_all: bool = False) -> dict[str, Any]:
    """One case: build the prior (nominal type, other programmes; ``training`` replaces the
    default list), replay unit #1, and the figures beside probe-and-hold at the same Q_prod.
    ``change_goal``: the change-probing rule on, its thresholds derived from the prior's
    held-out training programme (``change_from_all``: all its programmes, pooled) for this goal
    share (talc_model.probing.change_threshold)."""
    # heavy: scipy.signal only when a prior is built
    from talc_model.prior.talc import build_talc_prior, talc_with_prior, training_labels
    cache = {} if cache is None else cache
    train = prior_training(case, training)
    recs = [_simulate("nmv5000", s, seed, cache) for s, seed in train]
    prior = build_talc_prior(recs, config, machine="nmv5000", sources=training_labels(train),
                             **dict(prior_overrides or {}))
    run = _simulate(machine_instance("nmv5000", PLANT_UNIT), case, seed, cache)
    model = talc_with_prior(config, prior)
    thresholds = derive_change_thresholds(model, recs if change_from_all else recs[-1:], change_goal) \
        if change_goal else None
    noise = probe_noise(model.component_names)
    t0 = time.perf_counter()
    result = run_virtual_experiment(run, model, probe_noise_um=noise, probe_resolution_um=PROBE_RESOLUTION_UM,
                                    seed=seed, compute_metrics=False)
    wall = time.perf_counter() - t0
    status = model.status(float(result.time_s[-1]))
    figures, _ = beside_probe_and_hold(result, status.q_prod_pct, noise, PROBE_RESOLUTION_UM)
    whole = figures["whole_run"]
    return {"case": case, "prior_training": training_labels(train), "q_prod_pct": status.q_prod_pct,
            "no_good_phases": status.no_good_phases, "probing_cycles": status.probing_cycles,
            "parameter_updates": status.parameter_updates,
            "p99_lin_um": whole["model"]["p99_lin_um"], "p99_ang_um_per_m": whole["model"]["p99_ang_um_per_m"],
            "components": {c: v["p99"] for c, v in whole["model"]["components"].items()},
            "probe_and_hold_p99_lin_um": whole["probe_and_hold"]["p99_lin_um"],
            "probe_and_hold_p99_ang_um_per_m": whole["probe_and_hold"]["p99_ang_um_per_m"],
            "ratio": whole["p99_lin_ratio"], "replay_wall_s": wall, "change_thresholds": thresholds,
            "no_good_at_h": [round(e["t_s"] / 3600.0 - result.time_s[0] / 3600.0, 1)
                             for e in model.events if e.get("event") == "no_good"],
            "largest_residuals": error_location(result, model.component_names)}


def derive_change_thresholds(model, recordings, goal: float) -> dict[str, dict[str, float]]:
    """The change-probing thresholds of ``model`` (TALC started from its prior) derived on the
    prior's training ``recordings`` (pooled; never the evaluated run), set on the model."""
    # heavy: scipy.signal only when a prior is built
    from talc_model.probing.change_threshold import prior_change_thresholds
    from talc_model.prior.talc import grid_from_recording
    cfg = model.config
    grids = [grid_from_recording(r, cfg) for r in recordings]
    interval = max(1, int(round(cfg.post_cp_interval_h * 3600.0 / cfg.model_step_s)))
    noise = {c: math.sqrt(model._probe_noise_var(c)) for c in model.component_names}
    groups = {c: "angular" if c in cfg.angular_components else "linear" for c in model.component_names}
    out = prior_change_thresholds(model.prior_models, [g[0] for g in grids], [g[1] for g in grids], interval,
                                  noise, groups, goal)
    model.change_thresholds = np.array([out[c]["threshold"] for c in model.component_names])
    return out


def format_row(r: Mapping[str, Any]) -> str:
    return (f"{r['case']:<15} P99_lin {r['p99_lin_um']:5.2f} um  P99_ang {r['p99_ang_um_per_m']:5.2f} um/m  "
            f"Q_prod {r['q_prod_pct']:6.2f} %  NG {r['no_good_phases']:2d}  probe-and-hold "
            f"{r['probe_and_hold_p99_lin_um']:5.2f} um / {r['probe_and_hold_p99_ang_um_per_m']:5.2f} um/m  "
            f"ratio {r['ratio']:.2f}")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m thermal_eval.replay.prior_cases", description=__doc__.split("\n\n")[0])
    p.add_argument("--case", action="append", choices=CASES, help="a case (repeatable; default all six)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the shipped TALC configuration (YAML value)")
    p.add_argument("--prior-na-max", type=int, default=1, help="largest n_a of the prior (default 1)")
    p.add_argument("--prior-nb-max", type=int, default=8, help="largest n_b of the prior (default 8)")
    p.add_argument("--seed", type=int, default=RUN_SEED, help="seed of the run and its probe noise (default 0; "
                   "the priors' training runs use 101 on)")
    p.add_argument("--training", help="comma-separated training programmes of the priors instead of "
                   "thermal-comp prior's (the last one chooses the orders; seeds 101, 102, ... in this order)")
    p.add_argument("--change-goal", type=float, help="the change-probing rule on, its thresholds derived from "
                   "each prior's held-out training programme for this goal share (e.g. 0.5; default off)")
    p.add_argument("--change-from-all", action="store_true", help="derive them from all the prior's training "
                   "programmes pooled instead of its held-out one")
    p.add_argument("--json", type=pathlib.Path, help="write every figure here")
    p.add_argument("--detail", action="store_true", help="also print no-good times and the largest residuals")
    args = p.parse_args(argv)
    try:
        overrides = parse_overrides(args.set)
    except ReplayInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    training = [s.strip() for s in args.training.split(",") if s.strip()] if args.training else None
    if training is not None:
        unknown = sorted(set(training) - set(scenario_names("nmv5000")))
        if unknown:
            print(f"error: --training {args.training!r}: {unknown} are not nmv5000 scenarios", file=sys.stderr)
            return 2
    config = shipped_config()
    config.update(overrides)
    cache: dict = {}
    rows = []
    for case in args.case or CASES:
        r = run_case(case, config, cache, {"na_max": args.prior_na_max, "nb_max": args.prior_nb_max},
                     args.seed, training, args.change_goal, args.change_from_all)
        rows.append(r)
        print(format_row(r), flush=True)
        if r["change_thresholds"]:
            print("    change thresholds (x probe noise; share, hold P99): " + ", ".join(
                f"{c} {v['threshold']:.1f} ({v['share']:.2f}, {v['hold_p99']:.2f})"
                for c, v in r["change_thresholds"].items()), flush=True)
        if args.detail:
            print(f"    no-good phases at h: {r['no_good_at_h']}")
            for loc in r["largest_residuals"]:
                print(f"    {loc['component']}: " + ", ".join(f"{h} h {v} ({ph[:4]})" for h, v, ph in loc["peaks"]))
    worst = max((r["ratio"] for r in rows if math.isfinite(r["ratio"])), default=math.nan)
    print(f"worst ratio {worst:.2f} (goal <= 0.5); lowest Q_prod {min(r['q_prod_pct'] for r in rows):.2f} %")
    if args.json:
        args.json.write_text(json.dumps({"config_overrides": overrides, "training": training, "rows": rows},
                                        indent=1, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
