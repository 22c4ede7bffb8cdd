"""``thermal-comp bench twin-init``: a twin for a machine without a preset, from one recording.

(a) nmv5000 units that differ structurally from the type (thermal_eval.learn.units), NO preset
given: twin init from the first 24 h of the cell's own recording (no-prior TALC probing), a
TALC prior on that twin, TALC from it from 24 h on; the ratio of P99_lin to probe-and-hold over
the rest of the run beside the no-prior TALC running on and the type's prior (which needs the
preset). Default seeds 26-27, reported before (21-25 were looked at while setting the
identification, 32-35 reported after; docs/twin_init.md says which code saw which seeds).
(a') the same units with an adoption test (adoption_case.py): the init-twin prior's TALC runs beside
the no-prior one over 24-48 h and takes over at 48 h only if it predicted those probes better.
(b) FL_THERMAL: the init twin's open-loop MAE on the test and validation rows beside the lagged
ridge, the training mean and a static regression (units_case.py, fl_case.py), and its soft
sensors as an ``evaluate`` model in adaptive mode (<= 1 probing per hour, six probe phases)
beside every data-only adaptive row (fl_adaptive.py).
``--sections=units,adoption,fl`` picks the parts (default all), ``--seeds=24,25`` and
``--kinds=links,gain`` the units (default the reported seeds, every kind), ``--csv=PATH`` the
FL_THERMAL file.
Writes ``twin_init.json`` (units and FL rows) into the output folder.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import tempfile

from thermal_eval.learn.units import KINDS
from thermal_eval.twin_init.adoption_case import adopted_case
from thermal_eval.twin_init.fl_adaptive import PROBE_PHASES
from thermal_eval.twin_init.fl_case import fl_case
from thermal_eval.twin_init.units_case import unit_case

HOURS, INIT_H = 178.0, 24.0
#: reported seeds; 21-25 were looked at while setting the identification, 32-35 were reported later
SEEDS = (26, 27)
QUICK = {"kinds": ("links",), "seeds": (22,), "hours": 72.0}
SECTIONS = ("units", "adoption", "fl")


def _units(kinds, seeds, hours, root: pathlib.Path, figures: dict) -> list[dict]:
    units = []
    cases = [(k, s) for s in seeds for k in kinds]
    for i, (kind, seed) in enumerate(cases, 1):
        print(f"[{i}/{len(cases)}] unit #{seed} ({kind}) ...", flush=True)
        r = unit_case(kind, seed, hours, INIT_H, root / f"{kind}_{seed}")
        units.append(r)
        for name, v in r["ratios"].items():
            figures[f"twin_init.{kind}_{seed}.ratio.{name}"] = round(v, 3)
        print(f"  {r['truth']}; {r['hidden_bodies']} hidden bodies; {r['probes_first_day']} probes in the first "
              f"{INIT_H:g} h; ratio to probe-and-hold from {INIT_H:g} h: "
              + ", ".join(f"{k} {v:.3f}" for k, v in r["ratios"].items())
              + f"; twin init {r['wall_s']['twin_init']} s, prior {r['wall_s']['prior']} s", flush=True)
    return units


def _adoption(kinds, seeds, hours, root: pathlib.Path, figures: dict) -> list[dict]:
    rows = []
    for kind, seed in [(k, s) for s in seeds for k in kinds]:
        print(f"adoption test: unit #{seed} ({kind}) ...", flush=True)
        r = adopted_case(kind, seed, hours, root / f"adopt_{kind}_{seed}")
        rows.append(r)
        for name, v in r["ratios"].items():
            figures[f"twin_init.adoption.{kind}_{seed}.ratio.{name}"] = round(v, 3)
        print(f"  {'adopted' if r['adopted'] else 'NOT adopted'} at 48 h ({r['reason']}); ratio from 48 h: "
              + ", ".join(f"{k} {v:.3f}" for k, v in r["ratios"].items()), flush=True)
    return rows


def options(args: argparse.Namespace | None) -> argparse.Namespace:
    """The suite's own options from ``thermal-comp bench``'s extra arguments."""
    ap = argparse.ArgumentParser(prog="thermal-comp bench twin-init")
    ap.add_argument("--sections", default=",".join(SECTIONS),
                    help="comma-separated parts to run: " + ", ".join(SECTIONS) + " (default: all)")
    ap.add_argument("--csv", default=None, help="FL_THERMAL CSV (default: the shared data folder's)")
    ap.add_argument("--seeds", default=None, help="comma-separated unit seeds (default: "
                    + ",".join(map(str, SEEDS)) + ")")
    ap.add_argument("--kinds", default=None, help="comma-separated unit kinds: " + ", ".join(KINDS) + " (default: all)")
    opts = ap.parse_args(list(getattr(args, "extra", None) or []))
    opts.sections = [s.strip() for s in opts.sections.split(",") if s.strip()]
    bad = [s for s in opts.sections if s not in SECTIONS]
    if bad:
        ap.error(f"--sections: {bad[0]!r} is not one of {', '.join(SECTIONS)}")
    opts.kinds = tuple(k.strip() for k in opts.kinds.split(",") if k.strip()) if opts.kinds else None
    bad = [k for k in opts.kinds or () if k not in KINDS]
    if bad or opts.kinds == ():
        ap.error(f"--kinds: {bad[0] if bad else opts.kinds!r} is not one of {', '.join(KINDS)}")
    try:
        opts.seeds = tuple(int(s) for s in opts.seeds.split(",") if s.strip()) if opts.seeds else None
    except ValueError:
        ap.error(f"--seeds: {opts.seeds!r} must be comma-separated integers")
    if opts.seeds == ():
        ap.error("--seeds: names no seed")
    return opts


def _fl(root: pathlib.Path, csv: str | None, figures: dict) -> dict:
    print("FL_THERMAL: twin init on the training rows ...", flush=True)
    fl = fl_case(root / "fl_thermal", csv)
    for ch, row in fl["rows"].items():
        for name, v in row.items():
            figures[f"twin_init.fl.{ch}.{name}.test_mae_um"] = round(v["test_mae_um"], 3)
        print(f"  {ch}: open loop, test [validation] MAE um: " + ", ".join(
            f"{n} {v['test_mae_um']:.3f} [{v['validation_mae_um']:.3f}]" for n, v in row.items()), flush=True)
    ad = fl["adaptive"]
    for ch, row in ad["channels"].items():
        print(f"  {ch}: adaptive, phase mean of {PROBE_PHASES}, test [validation] MAE um: " + ", ".join(
            f"{n} {v[0]:.3f} [{v[1]:.3f}]" for n, v in row.items() if isinstance(v, list)), flush=True)
    for ref in ("better_than_best_row", "better_than_best_of_each_channel"):
        for k, v in ad[ref].items():
            figures[f"twin_init.fl.adaptive.{ref}.{k}"] = v
    print(f"  twin row below {ad['best data-only row']} (evaluate's best data-only adaptive row) on "
          f"{ad['better_than_best_row']}, below the best data-only row of each channel on "
          f"{ad['better_than_best_of_each_channel']} of {len(ad['channels'])} channels", flush=True)
    return fl


def run(args: argparse.Namespace | None = None) -> dict:
    quick = bool(getattr(args, "quick", False)) if args is not None else False
    opts = options(args)
    kinds, seeds, hours = (QUICK["kinds"], QUICK["seeds"], QUICK["hours"]) if quick else (KINDS, SEEDS, HOURS)
    kinds, seeds = opts.kinds or kinds, opts.seeds or seeds
    root = pathlib.Path(getattr(args, "out_dir", None) or tempfile.mkdtemp(prefix="bench_twin_init_")) / "twin_init"
    figures: dict = {"twin_init.hours": hours, "twin_init.init_h": INIT_H}
    units, adopted, fl = [], [], None
    if "units" in opts.sections:
        units = _units(kinds, seeds, hours, root, figures)
        ratios = [u["ratios"]["init-twin prior from 24 h"] for u in units]
        figures["twin_init.worst_ratio"] = round(max(ratios), 3) if ratios else math.nan
        figures["twin_init.units_at_most_0_5"] = sum(r <= 0.5 for r in ratios)
        print(f"twin init: ratio from {INIT_H:g} h {min(ratios):.3f}-{max(ratios):.3f} over {len(ratios)} units "
              f"({figures['twin_init.units_at_most_0_5']} at most 0.5)", flush=True)
    if "adoption" in opts.sections:
        adopted = _adoption(kinds, seeds, hours, root, figures)
    if "fl" in opts.sections:
        fl = _fl(root, opts.csv, figures)
    root.mkdir(parents=True, exist_ok=True)
    (root / "twin_init.json").write_text(json.dumps({"units": units, "adoption": adopted, "fl_thermal": fl},
                                                   indent=1, default=str) + "\n")
    print(f"details {root / 'twin_init.json'}")
    return figures
