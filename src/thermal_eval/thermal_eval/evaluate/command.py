"""The work of ``thermal-comp evaluate`` (:mod:`thermal_eval.evaluate.cli` parses the arguments):
load the recording, run every model and baseline, write evaluation.json/.png/.rrd, print the table."""
from __future__ import annotations

import argparse
import pathlib
import sys

from thermal_comp_common.recording_csv import RecordingError
from thermal_comp_common.runtime.engine_options import engine_from_args
from thermal_comp_common.runtime.task_engine import TaskEngineError
from thermal_twin.calibrate.column_mapping import MappingError

from thermal_eval.datasets import DatasetError, resolve_runs
from thermal_eval.evaluate import report
from thermal_eval.datasets.command import run_dataset
from thermal_eval.evaluate.adaptive import AdaptiveSettingsError, ProbingBudget, phase_budgets
from thermal_eval.evaluate.model_rows import CLOSED_LOOP
from thermal_eval.evaluate.run import available_models, evaluate
from thermal_eval.evaluate.spec import SpecError, check_spec, load_evaluation_data, load_spec


def spec_from_args(args: argparse.Namespace) -> dict:
    spec = load_spec(args.spec)
    check_spec(spec)
    for key in ("temperatures", "displacements", "inputs"):
        v = getattr(args, key)
        if v is not None:
            spec[key] = list(v)
    units = dict(spec.get("units") or {})
    for u in args.unit:
        if "=" not in u:
            raise SpecError(f"--unit {u!r}: expected COLUMN=UNIT")
        k, v = u.split("=", 1)
        units[k.strip()] = v.strip()
    spec["units"] = units
    split = dict(spec.get("split") or {})
    try:
        if args.split:
            tr, va, te = (float(x) for x in args.split.split(","))
            split.update(train=tr, validation=va, test=te)
        if args.split_rows:
            a, b = (int(x) for x in args.split_rows.split(","))
            split.update(train_end=a, held_out_boundary=b)
    except ValueError:
        raise SpecError(f"--split {args.split!r} / --split-rows {args.split_rows!r}: expected numbers "
                        "separated by commas (3 fractions / 2 rows)") from None
    if args.test_first:
        split["order"] = ["test", "validation"]
    spec["split"] = split
    if args.sample_period_s is not None:
        spec["sample_period_s"] = args.sample_period_s
    return spec


def _out_dir(path: str, force: bool) -> pathlib.Path:
    out = pathlib.Path(path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not force:
        raise FileExistsError(f"--out {str(out)!r} exists and is not empty (use --force to write into it)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def run(args: argparse.Namespace) -> int:
    """Evaluate as the parsed arguments say; the exit code (0 done, 2 bad input, 3 --out not empty)."""
    try:
        out = _out_dir(args.out, args.force)
    except FileExistsError as exc:
        print(f"thermal-comp evaluate: {exc}", file=sys.stderr)
        return 3
    try:
        budget = ProbingBudget(args.probe_every_h, args.max_probes_per_h, args.tolerance_um,
                               probe_resolution_um=args.probe_resolution_um, bucket_credit=args.bucket_credit)
        phase_budgets(budget, args.probe_phases)
        entries = resolve_runs(args.recording)
        if len(entries) > 1 or args.segments or args.runs_split:
            return run_dataset(args, out, entries, budget, spec_from_args(args))
        data = load_evaluation_data(entries[0].path, spec_from_args(args), args.map_file, args.map)
        models = available_models(data, args.models, args.also)
        engine = engine_from_args(args)
    except (SpecError, MappingError, RecordingError, AdaptiveSettingsError, TaskEngineError, FileNotFoundError,
            DatasetError, ValueError) as exc:
        print(f"thermal-comp evaluate: {exc}", file=sys.stderr)
        return 2
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    try:
        bad = [c for c in args.closed_loop if c not in CLOSED_LOOP]
        if bad:
            raise SpecError(f"--closed-loop: {bad[0]!r} is not one of {sorted(CLOSED_LOOP)}")
    except SpecError as exc:
        print(f"thermal-comp evaluate: {exc}", file=sys.stderr)
        return 2
    result = evaluate(data, models=models, adaptive=not args.open_loop_only, budget=budget,
                      show_progress=not args.no_progress, engine=engine, closed_loop=args.closed_loop,
                      probe_phases=args.probe_phases, load_probing=args.load_probing)
    figures = result.figures
    figures["outputs"] = {"json": str(out / "evaluation.json"), "png": str(report.plot(data, result, out))}
    if not args.no_rerun:
        figures["outputs"]["rerun"] = str(report.write_rerun(data, result, out))
    report.write_json(figures, out)
    report.print_table(figures)
    print(f"wrote {', '.join(figures['outputs'].values())}")
    return 0
