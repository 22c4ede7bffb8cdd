"""``thermal-comp bench learn --runs``: learning a unit from several daily runs against learning
it from its first run only, scored on unseen runs of the same unit.

For every structural unit (learn.units, on top of the type's unit-to-unit variation of its seed)
``DAYS + UNSEEN`` runs of ``RUN_H`` hours of talc-178h-dry are simulated, each its own seeded
programme and hall, each from rest, and probed as a cell would on its own clock (every
``EVERY_H`` hours from a seeded offset, Table 5.4 noise, 0.25 um resolution; errors since the
run's start). ``learn`` sees the cell's view only (no true hall, no ground truth). Two learnings
per unit, both by ``learn_runs`` with the same rule (no validation run: the last quarter of every
training run decides): from the first run only, and from the ``DAYS`` daily runs; the last
``UNSEEN`` runs are the test runs of both. Printed per unit, pooled over the unseen runs' probes:
RMSE per component of the type's and each unit twin open loop, the adaptive model from the
type's prior and from each adopted unit prior (a fresh model per run), holding the run's last
probe, the training probes' mean and the static regression of each learning. No rclpy.
"""
from __future__ import annotations

import json
import math
import pathlib
from typing import Callable

import numpy as np

from thermal_comp_common.components import is_angular
from thermal_comp_common.recording_csv import write_recording_csv
from thermal_comp_common.run_splits import run_splits
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

from thermal_eval.learn.probes import cell_view
from thermal_eval.learn.runs.command import learn_runs
from thermal_eval.learn.runs.sources import cell_runs
from thermal_eval.learn.units import structural_unit
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM, probe_noise

SCENARIO, RUN_H, EVERY_H, DAYS, UNSEEN = "talc-178h-dry", 12.0, 2.0 / 3.0, 3, 2
#: units of the section (kind, seed): seeds 21-22 never looked at while building learn
UNITS = (("extra_source", 21), ("links", 21), ("gain", 21), ("hall_bias", 22), ("chiller", 22), ("hall_drift", 22))
#: optimiser iterations of each learning
NFEV = 10


def unit_runs(kind: str, seed: int, folder: pathlib.Path) -> list[str]:
    """The unit's ``DAYS + UNSEEN`` runs as recording CSVs (module docstring); their paths."""
    unit = structural_unit(kind, seed)
    comps = list(unit.machine.errors)
    noise = probe_noise(comps)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for day in range(DAYS + UNSEEN):
        run_seed = 1000 * seed + day
        rec = simulate(unit.machine, make_timeline("nmv5000", SCENARIO, hours=RUN_H, seed=run_seed),
                       seed=run_seed).to_recording()
        rng = np.random.default_rng(run_seed)
        first = rng.uniform(0.1, EVERY_H) * 3600.0
        idx = np.unique(np.searchsorted(rec.time_s, np.arange(first, RUN_H * 3600.0, EVERY_H * 3600.0)))
        cols = dict(cell_view(rec, unit.machine).columns)
        for c in comps:
            col = np.full(len(rec), np.nan)
            v = rec.columns[c][idx] - rec.columns[c][0] + rng.normal(0.0, noise[c], idx.size)
            col[idx] = np.round(v / PROBE_RESOLUTION_UM) * PROBE_RESOLUTION_UM
            cols[c] = col
        paths.append(str(folder / f"day{day + 1}.csv"))
        write_recording_csv(paths[-1], rec.time_s, cols)
    return paths


def _learn(paths: list[str], n_train: int, out: pathlib.Path, priors: bool, words: bool, progress) -> dict:
    runs = cell_runs(paths[:n_train] + paths[-UNSEEN:])
    test = ",".join(r.name for r in runs[-UNSEEN:])
    fold = run_splits([r.entry for r in runs], f"test={test}")[0]
    return learn_runs("nmv5000", runs, fold, out, max_nfev=NFEV, progress=progress, build_priors=priors, words=words)


def unit_case(kind: str, seed: int, root: pathlib.Path, priors: bool, words: bool,
              progress: Callable[[str], None]) -> dict:
    paths = unit_runs(kind, seed, root / f"{kind}_{seed}" / "runs")
    reps = {"first run": _learn(paths, 1, root / f"{kind}_{seed}" / "first", priors, words, progress),
            f"{DAYS} runs": _learn(paths, DAYS, root / f"{kind}_{seed}" / "days", priors, words, progress)}
    table: dict[str, dict] = {}
    for arm, rep in reps.items():
        pooled = rep["scores"]["pooled"]["test"]
        for name, row in pooled.items():
            shared = name in ("hold last probe", "twin (type), open loop") or name.endswith("type prior")
            table[name if shared else f"{name} ({arm})"] = {c: v["rmse"] for c, v in row.items()}
    return {"kind": kind, "seed": seed, "truth": structural_unit(kind, seed).truth,
            "adopted": {arm: rep["adoption"]["adopt"] for arm, rep in reps.items()},
            "reasons": {arm: rep["adoption"]["reason"] for arm, rep in reps.items()},
            "words": {arm: [w["what"] for w in (rep["structure"] or {}).get("words", [])] for arm, rep in reps.items()},
            "wall_s": {arm: rep["wall_s"]["total"] for arm, rep in reps.items()}, "rmse": table}


def _ratio(row: dict, hold: dict, linear: bool = False) -> float:
    """Mean over the components (``linear``: the linear ones) of RMSE / holding's RMSE."""
    r = [row[c] / hold[c] for c in hold if math.isfinite(row.get(c, math.nan)) and hold[c] > 0
         and not (linear and is_angular(c))]
    return float(np.mean(r)) if r else math.nan


def table_text(u: dict) -> str:
    rows = u["rmse"]
    hold = rows["hold last probe"]
    comps = list(hold)
    lines = [f"    {'predictor':44} " + " ".join(f"{c:>6}" for c in comps) + "   / hold"]
    for name, row in rows.items():
        lines.append(f"    {name:44} " + " ".join(f"{row[c]:6.2f}" for c in comps) + f"   {_ratio(row, hold):6.2f}")
    return "\n".join(lines)


#: the rows of the summary table (predictor name as in the report, arm or None for the shared ones)
SUMMARY = (("hold last probe", None), ("twin (type), open loop", None), ("adaptive, type prior", None),
           ("twin (unit), open loop", "first run"), ("twin (unit), open loop", f"{DAYS} runs"),
           ("adaptive, unit prior", "first run"), ("adaptive, unit prior", f"{DAYS} runs"),
           ("training mean", f"{DAYS} runs"), ("static regression", f"{DAYS} runs"))


def summary_markdown(cases: list[dict]) -> str:
    """Per unit, each predictor's mean over the components of RMSE / holding's RMSE on the unseen
    runs' probes (all components / the linear ones: the angular ones sit at the probe noise), and
    whether each learning was adopted (runs.md, the table of docs/learn.md)."""
    head = [n if arm is None else f"{n} ({arm})" for n, arm in SUMMARY]
    lines = ["| unit | what differs (hidden from learn) | adopted (first run / " + f"{DAYS} runs) | " + " | ".join(head)
             + " |", "|---|---|---|" + "---|" * len(head)]
    for u in cases:
        hold = u["rmse"]["hold last probe"]
        cells = [f"{_ratio(u['rmse'][h], hold):.2f} / {_ratio(u['rmse'][h], hold, True):.2f}"
                 if h in u["rmse"] else "-" for h in head]
        adopted = " / ".join("yes" if v else "no" for v in u["adopted"].values())
        lines.append(f"| #{u['seed']} {u['kind']} | {u['truth']} | {adopted} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def run_section(root: pathlib.Path, priors: bool = True, units=UNITS, words: bool = True) -> dict:
    """The section (module docstring); figures by name. ``words``: learn searches its words."""
    figures: dict = {"learn_runs.run_h": RUN_H, "learn_runs.days": DAYS, "learn_runs.unseen": UNSEEN}
    cases = []
    for k, (kind, seed) in enumerate(units, 1):
        print(f"[runs {k}/{len(units)}] unit #{seed} ({kind}): {DAYS + UNSEEN} runs of {RUN_H:g} h ...", flush=True)
        u = unit_case(kind, seed, root, priors, words, lambda m: None)
        cases.append(u)
        hold = u["rmse"]["hold last probe"]
        for name, row in u["rmse"].items():
            figures[f"learn_runs.{kind}_{seed}.{name}"] = round(_ratio(row, hold), 3)
        print(f"  {u['truth']}\n  adopted: " + "; ".join(f"{a}: {'yes' if v else 'no'} ({u['reasons'][a]})"
                                                       for a, v in u["adopted"].items())
              + f"\n  words: {u['words']}\n  learn wall s: {u['wall_s']}\n"
              + f"  RMSE on the {UNSEEN} unseen runs' probes (um, um/m), pooled:\n"
              + table_text(u), flush=True)
    root.mkdir(parents=True, exist_ok=True)
    (root / "runs.json").write_text(json.dumps(cases, indent=1, default=str) + "\n")
    (root / "runs.md").write_text(summary_markdown(cases))
    print(f"learn --runs: details {root / 'runs.json'}")
    return figures
