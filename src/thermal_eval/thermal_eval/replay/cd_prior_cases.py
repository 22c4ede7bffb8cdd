"""The characteristic-diagram prior on unit #1 beside probe-and-hold, with and without the machine
type's soft sensors among its candidate inputs (docs/prior.md, "Characteristic
diagrams").

``python -m thermal_eval.replay.cd_prior_cases [--case C ...] [--seed S ...] [--hours H] [--json OUT]``
builds, per case, the CD prior of the NOMINAL nmv5000 from ``thermal-comp prior --model cd``'s
training programmes without the case (seeds 101, 102, ...), replays **unit #1** (run seed S,
Table 5.4 probe noise and resolution) with ``CdPriorModel`` and prints P99_lin / P99_ang over the
whole run and its first 8 h, probe-and-hold at the model's own Q_prod over the same instants,
the ratio (goal <= 0.5), Q_prod and probes, for three variants: ``temperatures`` (the candidates
without soft sensors: temperatures, their low-passes and gradients; ``type_inputs: []``), ``soft sensors,
clamped`` (those plus every soft sensor of the type, ``twin:<node>`` / ``twin:<error>``, the
diagrams clamped at the grid) and ``soft sensors`` (extrapolating linearly along the soft
sensors: the CD prior's default). The forward selection on the prior's held-out programme picks
the inputs in all.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
from typing import Any, Sequence

import numpy as np

from thermal_comp.prior.programmes import SEED_BASE, TRAINING_SCENARIOS
from thermal_comp_common.components import is_angular
from thermal_comp_common.metrics import p99, p99_group
from thermal_twin.machine.instance import machine_instance
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

from thermal_eval.replay.baseline_beside import beside_probe_and_hold
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM, probe_noise
from thermal_eval.replay.virtual_experiment import run_virtual_experiment

CASES = ["load-case-A", "load-case-B", "load-case-C", "load-case-D", "talc-178h-dry"]
PLANT_UNIT = 1


def variants() -> dict[str, dict[str, Any]]:
    """The prior configurations compared (the rest are the CD prior's defaults)."""
    from talc_model.type_inputs import load_soft_sensors  # heavy: scipy.signal only for the type inputs
    names = load_soft_sensors("nmv5000", [], "cd_prior_cases", "'type_inputs'").names
    return {"temperatures": {"type_inputs": []},
            "soft sensors, clamped": {"type_model": "nmv5000", "type_inputs": names, "extrapolate_type_inputs": False},
            "soft sensors": {"type_model": "nmv5000", "type_inputs": names, "extrapolate_type_inputs": True}}


def _simulate(machine, scenario: str, seed: int, hours: float | None, cache: dict):
    key = ("nominal" if isinstance(machine, str) else f"unit {PLANT_UNIT}", scenario, seed, hours)
    if key not in cache:
        cache[key] = simulate(machine, make_timeline("nmv5000", scenario, hours=hours, seed=seed),
                              seed=seed).to_recording()
    return cache[key]


def run_case(case: str, seed: int, hours: float | None, config: dict, cache: dict) -> dict[str, Any]:
    """One case and seed: prior without the case, replay of unit #1, beside probe-and-hold."""
    # heavy: scipy.signal, scikit-learn only when a prior is built
    from talc_model.prior.talc import training_labels
    from talc_model.prior.dispatch import model_from_prior
    from talc_model.prior.cd import build_cd_prior
    train = [(s, SEED_BASE + i) for i, s in enumerate(x for x in TRAINING_SCENARIOS["cd"]["nmv5000"] if x != case)]
    recs = [_simulate("nmv5000", s, sd, None, cache) for s, sd in train]
    t0 = time.perf_counter()
    prior = build_cd_prior(recs, config, machine="nmv5000", sources=training_labels(train))
    build_s = time.perf_counter() - t0
    run = _simulate(machine_instance("nmv5000", PLANT_UNIT), case, seed, hours, cache)
    model = model_from_prior("cd", {}, prior)
    noise = probe_noise(model.component_names)
    t0 = time.perf_counter()
    res = run_virtual_experiment(run, model, probe_noise_um=noise, probe_resolution_um=PROBE_RESOLUTION_UM,
                                 seed=seed, compute_metrics=False)
    wall = time.perf_counter() - t0
    st = model.status(float(res.time_s[-1]))
    fig, _ = beside_probe_and_hold(res, st.q_prod_pct, noise, PROBE_RESOLUTION_UM, seed=seed)
    whole = fig["whole_run"]
    first = np.asarray(res.time_s) <= res.time_s[0] + 8 * 3600.0
    per = {c: p99(np.asarray(res.true[c])[first], np.nan_to_num(np.asarray(res.predicted[c], float)[first]))
           for c in res.components}
    comps = res.components
    return {"case": case, "seed": seed, "hours": hours, "prior_training": training_labels(train),
            "prior_build_s": build_s, "replay_s": wall, "input_names": prior["input_names"],
            "validation_rms": prior["validation_rms"], "change_gain_prior": prior["change_gain"],
            "p99_lin_um": whole["model"]["p99_lin_um"], "p99_ang_um_per_m": whole["model"]["p99_ang_um_per_m"],
            "first_8h_p99_lin_um": p99_group(per, [c for c in comps if not is_angular(c)]),
            "first_8h_p99_ang_um_per_m": p99_group(per, [c for c in comps if is_angular(c)]),
            "probe_and_hold_p99_lin_um": whole["probe_and_hold"]["p99_lin_um"],
            "probe_and_hold_p99_ang_um_per_m": whole["probe_and_hold"]["p99_ang_um_per_m"],
            "ratio": whole["p99_lin_ratio"], "q_prod_pct": st.q_prod_pct, "probing_cycles": st.probing_cycles,
            "components": {c: v["p99"] for c, v in whole["model"]["components"].items()},
            "change_gain_end": {c: model.change_gain(c) for c in comps}}


def format_row(variant: str, r: dict[str, Any]) -> str:
    return (f"{r['case']:<14} seed {r['seed']} {variant:<21} P99_lin {r['p99_lin_um']:5.2f} / P99_ang "
            f"{r['p99_ang_um_per_m']:5.2f}  first 8 h {r['first_8h_p99_lin_um']:5.2f} / "
            f"{r['first_8h_p99_ang_um_per_m']:5.2f}  probe-and-hold {r['probe_and_hold_p99_lin_um']:5.2f} / "
            f"{r['probe_and_hold_p99_ang_um_per_m']:5.2f}  ratio {r['ratio']:.2f}  Q_prod {r['q_prod_pct']:.2f} % "
            f"({r['probing_cycles']})")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m thermal_eval.replay.cd_prior_cases", description=__doc__.split("\n\n")[0])
    p.add_argument("--case", action="append", choices=CASES, help="a case (repeatable; default all)")
    p.add_argument("--seed", action="append", type=int, help="run seed (repeatable; default 0 and 1)")
    p.add_argument("--hours", type=float, default=48.0, help="length of the run (default 48; 0: the whole programme)")
    p.add_argument("--variant", action="append", help="temperatures / soft sensors (default both)")
    p.add_argument("--json", type=pathlib.Path, help="write every figure here")
    a = p.parse_args(argv)
    all_variants = variants()
    chosen = a.variant or list(all_variants)
    unknown = [v for v in chosen if v not in all_variants]
    if unknown:
        print(f"error: --variant {unknown}: one of {list(all_variants)}", file=sys.stderr)
        return 2
    hours = a.hours if a.hours and a.hours > 0 else None
    cache: dict = {}
    rows = []
    for case in a.case or CASES:
        for seed in a.seed or [0, 1]:
            for v in chosen:
                r = run_case(case, seed, hours, all_variants[v], cache)
                rows.append({"variant": v, **r})
                print(format_row(v, r), flush=True)
                if a.json:
                    a.json.write_text(json.dumps(rows, indent=1, default=str) + "\n")
    ratios = [r["ratio"] for r in rows if r["variant"] == "soft sensors" and math.isfinite(r["ratio"])]
    if ratios:
        print(f"soft sensors: ratio {min(ratios):.2f}-{max(ratios):.2f} (goal <= 0.5)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
