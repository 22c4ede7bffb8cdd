"""The work of ``thermal-comp diagnose`` (:mod:`thermal_twin.diagnose.cli` parses the arguments):
diagnose the twin against the recording, write the report (and the augmented twin) and print the findings."""
from __future__ import annotations

import pathlib
import sys

import yaml

from thermal_twin.calibrate.fit import CalibrationError
from thermal_twin.calibrate.bounds import CalibrationSpecError
from thermal_twin.machine.schema import MachineSpecError, load_machine, save_machine
from thermal_twin.diagnose.diagnosis import DiagnosisError, diagnose
from thermal_twin.diagnose.effects import EFFECTS
from thermal_twin.diagnose.report import write_report
from thermal_twin.calibrate.column_mapping import (MappingError, empty_columns, name_mismatches, parse_mapping,
                                        read_real_recording)
from thermal_comp_common.runtime.engine_options import engine_from_args
from thermal_comp_common.recording_csv import RecordingError
from thermal_comp_common.runtime.task_engine import TaskEngineError


def run(args) -> int:
    """Diagnose as the parsed arguments say; the exit code (0 done, 1 failed, 2 bad arguments)."""
    effects = tuple(e.strip() for e in args.effects.split(",") if e.strip())
    bad = [e for e in effects if e not in EFFECTS]
    if bad:
        print(f"thermal-comp diagnose: --effects: {bad[0]!r} is not one of {', '.join(EFFECTS)}", file=sys.stderr)
        return 2
    if args.max_effects < 0:
        print(f"thermal-comp diagnose: --max-effects: {args.max_effects} must be >= 0", file=sys.stderr)
        return 2
    rec_path = pathlib.Path(args.recording)
    if not (rec_path.suffix.lower() in (".csv", ".mcap") or rec_path.is_dir()):
        print(f"thermal-comp diagnose: --recording: {rec_path} is neither a CSV nor a bag "
              f"(folder or .mcap)", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
        print(f"thermal-comp diagnose: --out: {out} exists and is not empty (use --force)", file=sys.stderr)
        return 2
    try:
        engine = engine_from_args(args)
        machine = load_machine(args.twin)
        rec = read_real_recording(rec_path, parse_mapping(args.map_file, args.map),
                                  args.temperatures_topic, args.errors_topic, args.sample_period_s)
        rec.warnings += name_mismatches(machine, rec)
        empty = empty_columns(rec)
        if empty:     # named, never dropped silently
            rec.warnings.append(f"columns without any value (not used): {', '.join(empty)}")
        for w in rec.warnings:
            print(f"warning: {w}", file=sys.stderr)
        section = None
        if args.bounds:
            raw = yaml.safe_load(pathlib.Path(args.bounds).read_text())
            section = (raw or {}).get("calibration", raw)
        d = diagnose(machine, rec, holdout_fraction=args.holdout_fraction, max_effects=args.max_effects,
                     min_improvement_pct=args.min_improvement, start_hour=args.start_hour,
                     effects=effects, max_lag_s=args.max_lag_h * 3600.0, progress=not args.quiet,
                     calibrate=args.calibrate, calibration_section=section, calibration_nfev=args.max_nfev,
                     unnamed=not args.no_unnamed, clock_offset=not args.no_clock_offset,
                     engine=engine)
    except (MachineSpecError, MappingError, RecordingError, DiagnosisError, CalibrationSpecError,
            CalibrationError, TaskEngineError, ValueError, OSError) as exc:
        print(f"thermal-comp diagnose: {exc}", file=sys.stderr)
        return 1
    out.mkdir(parents=True, exist_ok=True)
    if d.augmented_spec is not None:
        save_machine(d.augmented_spec, out / "twin_augmented.yaml")
        d.report["augmented_twin"] = "twin_augmented.yaml"
    if d.calibrated_spec is not None:
        save_machine(d.calibrated_spec, out / "twin_calibrated.yaml")
    paths = write_report(d.report, d.series, out, rerun=not args.no_rerun)
    cal = d.report.get("calibration")
    if cal:
        print(f"calibrated {cal['free_parameters']} parameters first (held-out improvement "
              f"{cal['holdout_improvement_pct']:.1f} %, {'used' if cal['used_as_base'] else 'not used'} as the base)")
        for m in cal["mis_calibrated"][:8]:
            print(f"mis-calibrated: {m['name']} {m['start']:.4g} -> {m['value']:.4g} {m['unit']}"
                  + (f" ({m['change_pct']:+.0f} %)" if m["change_pct"] is not None else ""))
    clk = d.report.get("clock_offset") or {}
    if clk.get("applied"):
        print(f"clock offset: measured channels {clk['shift_s']:+.4g} s ({clk['steps']:+.2f} steps) against the "
              f"inputs, removed before the search ({clk['channels_improved']} of {clk['channels_responsive']} "
              "responsive channels improved)")
    sel = d.report["selected"]
    for u in d.report.get("unnamed", []):
        c = d.report["channels"].get(u["channel"], {})
        print(f"unnamed (not in the vocabulary; nearest vocabulary word, said as such: {u['nearest_vocabulary_word']}): "
              f"{u['formula']}; {u['channel']} held-out RMSE {c.get('holdout_rmse_before', float('nan')):.4g} -> "
              f"{c.get('holdout_rmse_after', float('nan')):.4g} {c.get('unit', '')}")
    if sel == "none" and not d.report.get("unnamed"):
        print("selected: none (no effect improves the held-out fit significantly)")
    elif sel != "none":
        for h in sel:
            ps = ", ".join(f"{k}={v['value']:.4g} {v['unit']}" for k, v in h["params"].items())
            print(f"selected: {h['effect']} on {h['target']}"
                  + (f" driven by {h['driver']}" if h["driver"] else "")
                  + f" ({ps}); held-out improvement {h['holdout_improvement_pct']:.1f} %")
    for ch, c in d.report["channels"].items():
        print(f"  {ch:10s} held-out RMSE {c['holdout_rmse_before']:.4g} -> {c['holdout_rmse_after']:.4g} {c['unit']}")
    print("report: " + ", ".join(str(p) for p in paths.values()))
    return 0
