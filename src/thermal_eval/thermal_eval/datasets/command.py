"""``thermal-comp evaluate RUN RUN ...``: the data-set path of the evaluate command (several
recordings, a folder, a glob, a manifest, or one recording cut into ``--segments``)."""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

from thermal_comp_common.runtime.engine_options import engine_from_args
from thermal_eval.datasets.evaluate_runs import evaluate_runs
from thermal_eval.datasets.report_runs import print_runs
from thermal_eval.datasets.runs import load_runs, segments
from thermal_comp_common.recording_sources import RunEntry
from thermal_comp_common.run_splits import run_splits
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.run import available_models


def _default(o):
    return o.item() if hasattr(o, "item") else str(o)


def run_dataset(args: argparse.Namespace, out: pathlib.Path, entries: list[RunEntry], budget: ProbingBudget,
                spec: dict) -> int:
    """Load the runs with ``spec`` (the same columns, units and mapping flags as one recording),
    split them by run, evaluate every held-out run, write evaluation_runs.json. Raises the
    loaders' errors (the caller turns them into exit code 2)."""
    runs = load_runs(entries, spec, args.map_file, args.map)
    if args.segments:
        runs = [s for r in runs for s in segments(r, args.segments)]
    folds = run_splits([r.entry for r in runs], args.runs_split)
    models = available_models(runs[0].data, args.models, args.also)
    engine = engine_from_args(args)
    for r in runs:
        for note in r.notes:
            print(f"note: {r.entry.name}: {note}", file=sys.stderr)
    print(f"evaluate: {len(runs)} runs, {len(folds)} fold(s), "
          f"{sum(len(f.held_out()) for f in folds)} held-out run evaluation(s)", file=sys.stderr)
    figures = evaluate_runs(runs, folds, models=models, adaptive=not args.open_loop_only, budget=budget,
                            engine=engine, closed_loop=args.closed_loop, probe_phases=args.probe_phases,
                            run_start=args.run_start, rest_h=args.rest_h)
    path = out / "evaluation_runs.json"
    path.write_text(json.dumps(figures, indent=1, default=_default, allow_nan=True))
    print_runs(figures)
    print(f"wrote {path} ({figures['seconds']} s)")
    return 0
