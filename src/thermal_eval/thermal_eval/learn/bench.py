"""`thermal-comp bench learn`: the twin learns each unit from its cell's own probes.

For every structural unit (thermal_eval.learn.units: an extra source, changed hall links, a
thermo-elastic gain beyond tolerance, a biased hall sensor, a chiller that follows the hall, a
drifting hall sensor; seeds 17-18 by default (the reported ones), ``--seeds``/``--kinds``
choose; seeds 11-12 were looked at while setting the rules) a 178 h talc-178h-dry run is simulated. TALC
with the type's prior runs on it as a cell would and probes on its own schedule; the probes of
the first 48 h (Table 5.4 noise, 0.25 um resolution) plus the recorded temperatures and machine
inputs (no true hall, no ground truth) are all ``learn`` sees; it fits on 0-36 h and adopts the
unit twin only if it is better on the probes of 36-48 h. A prior is built on an adopted unit
twin, and a TALC started from it takes over at 48 h (not adopted: the type's prior runs on): it first runs over the recorded
history (inputs and the recorded probes), then on its own. Printed per unit, over the rest of
the run: P99_lin and its ratio to probe-and-hold at the model's own Q_prod for the type prior
running on, the type prior switched in the same way (the control) and the unit prior; each
component against half of Table 6.5; the learning's wall time.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import tempfile
import time

import numpy as np
import yaml

from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import load_prior
from thermal_comp.demo.summary import THESIS_TABLES
from thermal_comp.prior.build import cached_prior, default_config, training_scenarios
from thermal_comp_common.recording_csv import Recording
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

from thermal_eval.learn.command import UNIT_CONFIG, UNIT_PRIOR, learn
from thermal_eval.learn.probe_score import prequential_model
from thermal_eval.learn.probes import ProbeSet, cell_view
from thermal_eval.learn.runs.bench import UNITS as RUNS_UNITS, run_section
from thermal_eval.learn.units import KINDS, structural_unit
from thermal_eval.replay.baseline_beside import beside_in_window
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM, probe_noise
from thermal_eval.replay.virtual_experiment import run_virtual_experiment

SCENARIO, HOURS, TRAIN_H = "talc-178h-dry", 178.0, 48.0
#: reported seeds; seeds 11 and 12 were looked at while setting the adoption rule and the words' rules
SEEDS = (17, 18)
QUICK = {"kinds": ("extra_source", "links"), "seeds": (13,), "hours": 96.0, "train_h": 36.0}


def recorded_probes(result, rec: Recording, noise: dict, seed: int) -> ProbeSet:
    """The probes a cell running ``result``'s model recorded, as its bag holds them: the probe
    measures the residual (true error since the start minus the compensation applied at that
    instant) with Gaussian noise, quantised to the probe's resolution, and the total error is
    that reading plus what was applied. The noise is drawn as the replay's probe drew it (same
    seed, same order), so these are the readings the run itself learned from. Quantising the
    total instead would make the totals look quantised to the model's hold fall-back, which then
    takes a held probe for exact."""
    rng = np.random.default_rng(seed)
    idx = np.searchsorted(np.asarray(result.time_s, float), np.asarray(result.probe_times_s, float))
    values = {c: np.full(idx.size, np.nan) for c in result.components}
    for i, k in enumerate(idx):
        for c in result.components:
            applied = float(result.predicted[c][k])
            applied = applied if math.isfinite(applied) else 0.0
            m = float(result.true[c][k]) - applied
            if noise[c] > 0:
                m += rng.normal(0.0, noise[c])
            values[c][i] = round(m / PROBE_RESOLUTION_UM) * PROBE_RESOLUTION_UM + applied
    return ProbeSet(np.asarray(result.time_s, float)[idx], values, dict(noise), source="bench")


def _type_prior(progress):
    cfg = default_config("nmv5000", "talc")
    path, _ = cached_prior("nmv5000", cfg, training_scenarios("talc", "nmv5000"), progress=progress)
    return cfg, load_prior(path)


def _switched(rec: Recording, config: dict, prior: dict, probes: ProbeSet, start: int, noise: dict, seed: int):
    """A model started from ``prior`` that takes over the cell at row ``start``: it first runs over
    the recorded history (inputs, and the probes the cell recorded before ``start``), then runs
    on its own (its own probing) from ``start``; errors are those since the run's start."""
    model = model_from_prior("talc", config, prior)
    prequential_model(model, rec.slice(0, start), probes.window(t1=float(rec.time_s[start])))
    return run_virtual_experiment(rec, model, probe_noise_um=noise, probe_resolution_um=PROBE_RESOLUTION_UM,
                                  seed=seed, start=start, relative_errors=False, compute_metrics=False)


def _window(result, t_from: float, noise: dict, seed: int) -> dict:
    """The model beside probe-and-hold (at its own Q_prod) on the rows from ``t_from`` on."""
    q = result.final_status["q_prod_pct"]
    row = beside_in_window(result, np.asarray(result.time_s) >= t_from, q, noise, PROBE_RESOLUTION_UM, seed=seed)
    row["q_prod_pct"] = q
    return row


def unit_case(kind: str, seed: int, hours: float, train_h: float, out: pathlib.Path, progress) -> dict:
    unit = structural_unit(kind, seed)
    rec = simulate(unit.machine, make_timeline("nmv5000", SCENARIO, hours=hours, seed=seed), seed=seed).to_recording()
    cfg, prior = _type_prior(progress)
    noise = probe_noise(list(prior["talc_state"]["models"]))
    before = run_virtual_experiment(rec, model_from_prior("talc", cfg, prior), probe_noise_um=noise,
                                    probe_resolution_um=PROBE_RESOLUTION_UM, seed=seed, compute_metrics=False)
    t_train = float(rec.time_s[0]) + train_h * 3600.0
    probes = recorded_probes(before, rec, noise, seed)
    t0 = time.perf_counter()
    report = learn("nmv5000", cell_view(rec, unit.machine), probes, out, train_h, progress=progress)
    t_learn = time.perf_counter() - t0
    adopted = report["adoption"]["adopt"]
    start = int(np.searchsorted(rec.time_s, t_train))
    rows = {"before": _window(before, t_train, noise, seed)}
    rows["type switched"] = _window(_switched(rec, cfg, prior, probes, start, noise, seed), t_train, noise, seed)
    if adopted:
        unit_cfg = yaml.safe_load((out / UNIT_CONFIG).read_text())
        rows["after"] = _window(_switched(rec, unit_cfg, load_prior(out / UNIT_PRIOR), probes, start, noise, seed),
                                t_train, noise, seed)
    else:
        rows["after"] = rows["before"]       # not adopted: the cell keeps running with the type's prior
    half = {c: v / 2.0 for c, v in THESIS_TABLES[SCENARIO]["p99_compensated"].items()}
    per = {k: {c: v["p99"] for c, v in r["model"]["components"].items()} for k, r in rows.items()}
    per["probe-and-hold after"] = {c: v["p99"] for c, v in rows["after"]["probe_and_hold"]["components"].items()}
    moved = [p for p in report["parameters"] if p["at_bound"] or abs(p["change_pct"] or 0.0) >= 15.0]
    return {"unit": unit.name, "kind": kind, "seed": seed, "truth": unit.truth, "adopted": adopted,
            "adoption": report["adoption"]["reason"],
            "ratio_before": rows["before"]["p99_lin_ratio"], "ratio_after": rows["after"]["p99_lin_ratio"],
            "ratio_type_switched": rows["type switched"]["p99_lin_ratio"],
            "p99_lin_before_um": rows["before"]["model"]["p99_lin_um"],
            "p99_lin_after_um": rows["after"]["model"]["p99_lin_um"],
            "q_prod_before_pct": rows["before"]["q_prod_pct"], "q_prod_after_pct": rows["after"]["q_prod_pct"],
            "components_above_half_table_6_5": _above(per["after"], half),
            "components_above_half_table_6_5_before": _above(per["before"], half),
            "component_p99": per, "half_table_6_5": half,
            "learned_moves": [f"{p['name']} {p['change_pct']:+.0f} %{' (at bound)' if p['at_bound'] else ''}"
                              for p in moved if p["change_pct"] is not None],
            "learned_words": [w["what"] for w in report["structure"]["words"]],
            "structure_wall_s": report["wall_s"]["structure"],
            "held_out_probe_rmse": {k: {c: round(v[c]["rmse"], 3) if v[c]["rmse"] == v[c]["rmse"] else None
                                        for c in v} for k, v in report["held_out_scores"].items()},
            "learn_wall_s": round(t_learn, 1), "calibration_wall_s": report["wall_s"]["calibration"],
            "twin_simulated_h_per_s": report["twin_simulated_h_per_s"]}


def _above(p99: dict, half: dict) -> list[str]:
    return sorted(c for c, v in p99.items() if math.isfinite(v) and v > half.get(c, math.inf))


def components_text(r: dict) -> str:
    """Per component: P99 before / type switched / after / probe-and-hold, against half Table 6.5."""
    per, half = r["component_p99"], r["half_table_6_5"]
    rows = [f"    {'':6} {'before':>7} {'switched':>8} {'after':>7} {'p&h':>6} {'half 6.5':>8}"]
    for c in per["after"]:
        v = [per[k][c] for k in ("before", "type switched", "after", "probe-and-hold after")]
        flag = "  ABOVE" if v[2] > half.get(c, math.inf) else ""
        rows.append(f"    {c:6} {v[0]:7.2f} {v[1]:8.2f} {v[2]:7.2f} {v[3]:6.2f} {half.get(c, math.nan):8.2f}{flag}")
    return "\n".join(rows)


def components_markdown(units: list[dict]) -> list[str]:
    """P99 per component over the rest of the run (before -> after learning, um and um/m), in
    bold where above half of Table 6.5."""
    have = [u for u in units if "component_p99" in u]
    if not have:
        return []
    comps = list(have[0]["component_p99"]["after"])
    half = have[0]["half_table_6_5"]
    lines = ["| unit | " + " | ".join(f"{c} (half: {half[c]:g})" for c in comps) + " |",
             "|---|" + "---|" * len(comps)]
    for u in have:
        per = u["component_p99"]
        cells = [f"{per['before'][c]:.2f} -> " + (f"**{per['after'][c]:.2f}**" if per["after"][c] > half[c]
                                                  else f"{per['after'][c]:.2f}") for c in comps]
        lines.append(f"| #{u['seed']} {u['kind']} | " + " | ".join(cells) + " |")
    return lines


def parse(extra: list[str]) -> argparse.Namespace:
    """The suite's own options (after the bench's): which seeds and kinds of unit to run."""
    ap = argparse.ArgumentParser(prog="thermal-comp bench learn")
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help=f"unit seeds (default {list(SEEDS)})")
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=None, help="kinds of unit (default all)")
    ap.add_argument("--runs", action="store_true",
                    help="instead: learning from several daily runs against the first run only, scored on unseen "
                         "runs of the same unit (learn.runs.bench; --seeds/--kinds pick its units)")
    ap.add_argument("--no-words", action="store_true", help="with --runs: the joint calibration only, no word search")
    a = ap.parse_args(extra)
    if a.seeds and min(a.seeds) < 0:
        ap.error(f"--seeds: {a.seeds} must be >= 0")
    return a


def results_markdown(units: list[dict]) -> str:
    """The results table of docs/learn.md, generated from units.json's rows."""
    lines = ["| unit | what differs (hidden from learn) | adopted | words learned | type prior running on | "
             "type prior switched in | after learning | above half Table 6.5 after |", "|---|---|---|---|---|---|---|---|"]
    for u in units:
        lines.append(f"| #{u['seed']} {u['kind']} | {u['truth']} | {'yes' if u['adopted'] else 'no'} | "
                     f"{'; '.join(u.get('learned_words') or []) or '-'} | {u['ratio_before']:.3f} | "
                     f"{u['ratio_type_switched']:.3f} | {u['ratio_after']:.3f} | "
                     f"{', '.join(u['components_above_half_table_6_5']) or 'none'} |")
    lines += ["", *components_markdown(units)]
    ok = [u for u in units if u["ratio_after"] <= 0.15 and not u["components_above_half_table_6_5"]]
    lines += ["", f"{sum(u['adopted'] for u in units)} of {len(units)} unit twins adopted; "
              f"{sum(u['ratio_after'] <= 0.15 for u in units)} of {len(units)} units at ratio <= 0.15; "
              f"{len(ok)} of {len(units)} also with every component at most half of Table 6.5; "
              f"{sum(u['ratio_after'] > u['ratio_before'] for u in units)} worse than the type prior running on. "
              f"learn {min(u['learn_wall_s'] for u in units):.1f}-{max(u['learn_wall_s'] for u in units):.1f} s "
              f"per unit, twin {min(u['twin_simulated_h_per_s'] for u in units):.0f}-"
              f"{max(u['twin_simulated_h_per_s'] for u in units):.0f} simulated h/s in the calibration."]
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace | None = None) -> dict:
    quick = bool(getattr(args, "quick", False)) if args is not None else False
    own = parse(list(getattr(args, "extra", None) or []))
    if own.runs:
        units = [(k, s) for s in own.seeds for k in (own.kinds or KINDS)] if own.seeds else \
            [u for u in RUNS_UNITS if not own.kinds or u[0] in own.kinds]
        out = pathlib.Path(getattr(args, "out_dir", None) or tempfile.mkdtemp(prefix="bench_learn_")) / "learn_runs"
        return run_section(out, units=tuple(units), words=not own.no_words)
    kinds, seeds = (QUICK["kinds"], QUICK["seeds"]) if quick else (KINDS, SEEDS)
    kinds, seeds = tuple(own.kinds or kinds), tuple(own.seeds or seeds)
    hours, train_h = (QUICK["hours"], QUICK["train_h"]) if quick else (HOURS, TRAIN_H)
    root = pathlib.Path(getattr(args, "out_dir", None) or tempfile.mkdtemp(prefix="bench_learn_")) / "learn"
    figures: dict = {"learn.scenario": SCENARIO, "learn.hours": hours, "learn.train_h": train_h}
    units = []
    cases = [(k, s) for s in seeds for k in kinds]
    for i, (kind, seed) in enumerate(cases, 1):
        print(f"[{i}/{len(cases)}] unit #{seed} ({kind}) ...", flush=True)
        r = unit_case(kind, seed, hours, train_h, root / f"{kind}_{seed}", progress=lambda m: None)
        units.append(r)
        for key in ("ratio_before", "ratio_type_switched", "ratio_after", "learn_wall_s"):
            figures[f"learn.{kind}_{seed}.{key}"] = round(r[key], 3)
        figures[f"learn.{kind}_{seed}.adopted"] = r["adopted"]
        print(f"  {r['truth']}\n  ratio to probe-and-hold after {train_h:g} h: type prior running on "
              f"{r['ratio_before']:.3f}, type prior switched in {r['ratio_type_switched']:.3f}, "
              f"{'unit prior switched in' if r['adopted'] else 'NOT ADOPTED, type prior running on'} "
              f"{r['ratio_after']:.3f} (P99_lin {r['p99_lin_before_um']:.2f} -> {r['p99_lin_after_um']:.2f} um; "
              f"Q_prod {r['q_prod_before_pct']:.1f} / {r['q_prod_after_pct']:.1f} %); above half Table 6.5: "
              f"{', '.join(r['components_above_half_table_6_5']) or 'none'}; learn {r['learn_wall_s']} s "
              f"(calibration {r['calibration_wall_s']} s, words {r['structure_wall_s']} s, twin "
              f"{r['twin_simulated_h_per_s']} simulated h/s); adoption: {r['adoption']}; words: "
              f"{'; '.join(r['learned_words']) or 'none'}; moved: "
              f"{'; '.join(r['learned_moves']) or 'nothing beyond 15 %'}\n{components_text(r)}", flush=True)
    after = [u["ratio_after"] for u in units]
    figures["learn.worst_ratio_after"] = round(max(after), 3) if after else math.nan
    figures["learn.units_adopted"] = sum(u["adopted"] for u in units)
    figures["learn.units_worse_than_type_running_on"] = sum(u["ratio_after"] > u["ratio_before"] for u in units)
    root.mkdir(parents=True, exist_ok=True)
    (root / "units.json").write_text(json.dumps(units, indent=1, default=str) + "\n")
    (root / "units.md").write_text(results_markdown(units))
    print(f"learn: {figures['learn.units_adopted']} of {len(units)} unit twins adopted; worst ratio after "
          f"{figures['learn.worst_ratio_after']:.3f}; units worse than the type prior running on: "
          f"{figures['learn.units_worse_than_type_running_on']} of {len(units)}; details {root / 'units.json'}")
    return figures
