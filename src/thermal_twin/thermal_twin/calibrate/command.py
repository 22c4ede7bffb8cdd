"""The work of ``thermal-comp calibrate`` (:mod:`thermal_twin.calibrate.cli` parses the arguments):
fit the twin on the recording (or on several runs together, split by run) and write the
calibrated twin, the report and its plots."""
from __future__ import annotations

import pathlib
import sys

import yaml

from thermal_twin.calibrate.report import plot_input_estimate, write_report
from thermal_twin.calibrate.fit import CalibrationError, calibrate, left_out_lines, pick_channels
from thermal_twin.calibrate.runs import SPREAD_SHARE, calibrate_folds, check_same_columns, holdout_fold
from thermal_twin.calibrate.input_estimation import InputEstimationError, fill_missing_inputs, missing_inputs
from thermal_twin.calibrate.bounds import CalibrationSpecError
from thermal_twin.machine.schema import MachineSpecError, load_machine, save_machine
from thermal_twin.calibrate.column_mapping import (MappingError, empty_columns, name_mismatches, parse_mapping,
                                        read_real_recording)
from thermal_comp_common.runtime.engine_options import engine_from_args
from thermal_comp_common.recording_csv import RecordingError
from thermal_comp_common.recording_sources import DatasetError, resolve_runs
from thermal_comp_common.run_splits import run_splits
from thermal_comp_common.runtime.task_engine import TaskEngineError


def run(args) -> int:
    """Calibrate as the parsed arguments say; the exit code (0 done, 1 failed, 2 --out not empty)."""
    out = pathlib.Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
        print(f"thermal-comp calibrate: --out: {out} exists and is not empty (use --force)", file=sys.stderr)
        return 2
    try:
        engine = engine_from_args(args)
        machine = load_machine(args.twin)
        section = None
        if args.bounds:
            raw = yaml.safe_load(pathlib.Path(args.bounds).read_text())
            section = (raw or {}).get("calibration", raw)
        entries = resolve_runs(args.recording)
        if all(e.date for e in entries):
            entries = sorted(entries, key=lambda e: e.date)     # stable: the given order within a day
        split = _folds(args, entries) if len(entries) > 1 else _one_recording(args)
        recs, notes, estimates = _read_runs(args, machine, entries)
        say = None if args.quiet else (lambda s: print(s, file=sys.stderr))
        if split is None:
            frac = 1 / 3 if args.holdout_fraction is None else args.holdout_fraction
            r, runs, folds = calibrate(machine, recs[0], holdout_fraction=frac, section=section,
                                       max_nfev=args.max_nfev, progress=say, engine=engine,
                                       initial_state=args.initial_state), None, None
        else:
            folds = calibrate_folds(machine, recs, [e.name for e in entries], split, section=section,
                                    max_nfev=args.max_nfev, progress=say, engine=engine,
                                    initial_state=args.initial_state)
            r, runs = folds.written.result, folds.written.runs
    except (MachineSpecError, MappingError, CalibrationSpecError, RecordingError, CalibrationError,
            InputEstimationError, TaskEngineError, DatasetError, ValueError, OSError) as exc:
        print(f"thermal-comp calibrate: {exc}", file=sys.stderr)
        return 1
    out.mkdir(parents=True, exist_ok=True)
    save_machine(r.spec, out / "twin_calibrated.yaml")
    paths = write_report(r, out, machine.source_path or machine.name, ", ".join(x.source for x in recs), notes,
                         input_estimates=[e.as_dict() for _, e, _ in estimates], runs=runs, folds=folds)
    for name, e, rec in estimates:
        key = f"input_{e.input}" + (f"_{name}" if runs else "")
        paths[key] = out / f"input_estimate_{e.input}{f'_{name}' if runs else ''}.png"
        plot_input_estimate(e, rec.time_s, paths[key])
    rate = r.simulated_h / max(r.wall_s, 1e-9)
    print(f"calibrated {len(r.estimates)} parameters on {len(r.channels)} channels in {r.wall_s:.1f} s "
          f"({r.n_evals} twin evaluations, {rate:.0f} simulated h/s); cost {r.cost_before:.4g} -> "
          f"{r.cost_after:.4g} ({r.status})")
    _print_figures(r, runs, folds)
    unid = [e.param.name for e in r.estimates if any(f.startswith("not identified") for f in e.flags)]
    print(f"not identified by this recording: {len(unid)} of {len(r.estimates)}; "
          f"correlated pairs: {len(r.correlated)}")
    for line in left_out_lines(r.left_out_counts()):
        print(f"left out: {line}")
    for n in notes:
        print(f"note: {n}")
    print("report: " + ", ".join(str(p) for p in [out / "twin_calibrated.yaml", *paths.values()]))
    return 0


def _one_recording(args) -> None:
    """One recording is split in time: refuse a split by run, naming the flag and its value."""
    for flag, v in (("--holdout-runs", args.holdout_runs), ("--runs-split", args.runs_split)):
        if v is not None:
            raise CalibrationError(f"{flag} {v}: one recording is split in time (--holdout-fraction); "
                                   "give several recordings to split by run")


def _folds(args, entries) -> list:
    """The split by run the arguments name: ``--runs-split`` (evaluate's grammar) or
    ``--holdout-runs`` (the last K or named runs; default the last third), not both."""
    if args.holdout_fraction is not None:
        raise CalibrationError(f"--holdout-fraction {args.holdout_fraction}: {len(entries)} runs are split by "
                               "run (--holdout-runs K or NAME,NAME, or --runs-split)")
    if args.runs_split is not None:
        if args.holdout_runs is not None:
            raise CalibrationError(f"--runs-split {args.runs_split} and --holdout-runs {args.holdout_runs}: "
                                   "give one split")
        return run_splits(entries, args.runs_split)
    return [holdout_fold([e.name for e in entries], args.holdout_runs)]


def _print_figures(r, runs, folds) -> None:
    """Held-out RMSE per channel (pooled over the held-out runs, over every fold's when there
    are several), one line per run, and with several folds each parameter that moves between them."""
    several = folds is not None and len(folds.folds) > 1
    pooled = folds.pooled if folds is not None else None
    what = "held-out runs pooled over folds" if several else ("held-out runs pooled" if runs else "held-out")
    for c, v in r.channel_table().items():
        b, a = (pooled[c]["rmse_before"], pooled[c]["rmse_after"]) if pooled else \
            (v["holdout_rmse_before"], v["holdout_rmse_after"])
        gone = r.left_out_counts().get(c, {}).get("holdout", 0)
        print(f"  {c:10s} {what} RMSE {b:.4g} -> {a:.4g}"
              + (f" ({gone} held-out readings left out after gaps)" if gone and not runs else ""))
    shown = [(x, f["name"]) for f in folds.folds for x in f["runs"] if x["role"] != "train"] if several else \
        [(x, None) for x in runs or []]
    for x, fold in shown:
        print(f"  run {x['name']} ({x['role']}{f', fold {fold}' if fold else ''}): " + ", ".join(
            f"{c} {v['rmse_before']:.3g} -> {v['rmse_after']:.3g}" for c, v in x["channels"].items()))
    if several:
        moving = [p for p in folds.spread if p["moves"]]
        print(f"twin written: the fit on all {len(runs)} runs; parameters moving more than {SPREAD_SHARE:.0%} of "
              f"their range between folds (not pinned down by these runs): {len(moving)} of {len(folds.spread)}"
              + (": " + ", ".join(p["name"] for p in moving[:8]) + (" ..." if len(moving) > 8 else "")
                 if moving else ""))


def _read_runs(args, machine, entries) -> tuple[list, list[str], list[tuple]]:
    """Every run read with the same mapping and topics, each run's missing inputs estimated
    from its own temperatures; (recordings, notes, [(run name, estimate, its recording)])."""
    mapping = parse_mapping(args.map_file, args.map)
    raw = [read_real_recording(e.path, mapping, args.temperatures_topic, args.errors_topic, args.sample_period_s)
           for e in entries]
    if len(raw) > 1:
        check_same_columns(raw, [e.name for e in entries])   # before any estimate fills a column in
    recs, notes, estimates = [], [], []
    for entry, rec in zip(entries, raw):
        tag = f"run {entry.name}: " if len(entries) > 1 else ""
        found = list(rec.warnings) + name_mismatches(machine, rec)
        empty = empty_columns(rec)
        if empty:
            found.append(f"columns without any value (not used): {', '.join(empty)}")
        if missing_inputs(machine, rec):
            chans, _ = pick_channels(machine, rec)
            rec, est, said = fill_missing_inputs(machine, rec, chans, block_s=args.block_min * 60.0)
            found = said + found
            estimates += [(entry.name, e, rec) for e in est]
        recs.append(rec)
        notes += [tag + n for n in found]
    return recs, notes, estimates
