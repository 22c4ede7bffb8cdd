"""``thermal-comp evaluate REC --out DIR``: every model against honest baselines on your recording.

REC is a CSV (plain, with a BOM, or Excel-style ``;`` / decimal comma) or a bag. Columns: by
default the project's kinds (``*_c`` temperatures, ``*_um`` / ``E_*`` displacements, the rest
machine inputs); ``--temperatures/--displacements/--inputs`` take names or glob patterns,
``--map OLD=NEW`` / ``--map NAME*K`` / ``--map-file`` rename and scale (the calibrate mapping),
``--unit NAME=mm`` converts, ``--spec YAML`` holds all of it (docs/evaluate.md). Writes
evaluation.json, evaluation.png and evaluation.rrd into DIR and prints the table. Model rows run
serially, on ``--jobs N`` local processes or on a dask cluster (``--engine dask --address ...``).
Exit codes: 0 done, 2 bad input (named), 3 --out exists and is not empty (use --force).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

from thermal_comp_common.recording_csv import RecordingError
from thermal_comp_common.engine_options import add_engine_arguments, engine_from_args
from thermal_comp_common.task_engine import TaskEngineError
from thermal_twin.column_mapping import MappingError

from thermal_eval.adaptive_eval import AdaptiveSettingsError, ProbingBudget, phase_budgets
from thermal_eval.open_loop_models import OPT_IN
from thermal_eval.evaluation_spec import SpecError, check_spec, load_evaluation_data, load_spec


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp evaluate", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", metavar="REC", help="recording CSV, bag folder or .mcap file")
    ap.add_argument("--out", required=True, metavar="DIR", help="output folder (refused if not empty, see --force)")
    ap.add_argument("--force", action="store_true", help="write into a non-empty --out")
    ap.add_argument("--spec", metavar="YAML", help="columns, units, split and mapping in one file")
    ap.add_argument("--temperatures", nargs="+", metavar="COL", help="temperature columns (names or globs)")
    ap.add_argument("--displacements", nargs="+", metavar="COL", help="displacement channels (names or globs)")
    ap.add_argument("--inputs", nargs="*", metavar="COL", help="machine inputs (none: --inputs with no name)")
    ap.add_argument("--map", action="append", default=[], metavar="OLD=NEW|NAME*K", help="rename / scale a column")
    ap.add_argument("--map-file", metavar="YAML", help="column mapping file (columns:, scale:)")
    ap.add_argument("--unit", action="append", default=[], metavar="COL=UNIT",
                    help="unit of a column: um mm nm m in (displacements), C K F (temperatures)")
    ap.add_argument("--split", metavar="TRAIN,VAL,TEST", help="fractions in time order (default 0.6,0.2,0.2)")
    ap.add_argument("--split-rows", metavar="TRAIN_END,BOUNDARY", help="first validation row and first test row")
    ap.add_argument("--test-first", action="store_true", help="the test window comes before the validation window")
    ap.add_argument("--models", nargs="+", metavar="NAME", help="only these models (baselines always run)")
    ap.add_argument("--also", nargs="+", default=[], metavar="NAME",
                    help=f"the default models plus these (opt-in: {', '.join(OPT_IN)})")
    ap.add_argument("--closed-loop", nargs="+", default=[], metavar="NAME",
                    help="also the project's adaptive models with their own logic, within the budget: "
                         "agp_closed_loop (sigma_max recalibration), talc_closed_loop (calibration, no-good, updates); calibrated on the training rows: "
                         "talc_calibrated[_inputs][_load_probing], agp_calibrated")
    ap.add_argument("--open-loop-only", action="store_true", help="no adaptive mode")
    ap.add_argument("--probe-every-h", type=float, default=2.0, help="scheduled probing interval (h)")
    ap.add_argument("--max-probes-per-h", type=float, default=1.0,
                    help="cap on all probings after calibration, average per hour")
    ap.add_argument("--tolerance-um", type=float, default=1.0,
                    help="predicted change since the last probing that asks for one")
    ap.add_argument("--probe-resolution-um", type=float, default=0.0,
                    help="your probe's resolution: a predicted change below it (or below twice the noise of "
                         "a reading difference measured on the training rows) is not acted on (default 0)")
    ap.add_argument("--probe-phases", type=int, default=1, metavar="K",
                    help="score the adaptive mode at K phases of the probing clock (delayed by i/K of the "
                         "interval, each a full run with its own probings): mean and worst per channel (default 1)")
    ap.add_argument("--load-probing", action="store_true",
                    help="each model may also probe a few minutes after a machine-input step (spindle speed, "
                         "coolant...), from a token bucket: at most 1 + max-probes-per-h x the hours after "
                         "calibration; off/on, delay and bucket depth chosen per model on the training rows")
    ap.add_argument("--bucket-credit", type=float, default=1.0, choices=(0.0, 1.0),
                    help="with --load-probing: probings the bucket holds when calibration ends (1: the total may "
                         "exceed max-probes-per-h x hours by one; 0: never more than the rate on average)")
    add_engine_arguments(ap, default_jobs=1, what="model rows")
    ap.add_argument("--no-rerun", action="store_true", help="no evaluation.rrd")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


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
    return spec


def _out_dir(path: str, force: bool) -> pathlib.Path:
    out = pathlib.Path(path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not force:
        raise FileExistsError(f"--out {str(out)!r} exists and is not empty (use --force to write into it)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    from thermal_eval import evaluation_report as report
    from thermal_eval.evaluation_run import available_models, evaluate
    try:
        out = _out_dir(args.out, args.force)
    except FileExistsError as exc:
        print(f"thermal-comp evaluate: {exc}", file=sys.stderr)
        return 3
    try:
        budget = ProbingBudget(args.probe_every_h, args.max_probes_per_h, args.tolerance_um,
                               probe_resolution_um=args.probe_resolution_um, bucket_credit=args.bucket_credit)
        phase_budgets(budget, args.probe_phases)
        data = load_evaluation_data(args.recording, spec_from_args(args), args.map_file, args.map)
        models = available_models(data, args.models, args.also)
        engine = engine_from_args(args)
    except (SpecError, MappingError, RecordingError, AdaptiveSettingsError, TaskEngineError, FileNotFoundError,
            ValueError) as exc:
        print(f"thermal-comp evaluate: {exc}", file=sys.stderr)
        return 2
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    try:
        from thermal_eval.closed_loop_rows import CLOSED_LOOP
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
