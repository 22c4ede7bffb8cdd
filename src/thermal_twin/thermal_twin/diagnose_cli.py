"""Find what physics the twin lacks: compare it with a recording, locate, name, model, prove.

``thermal-comp diagnose --twin MACHINE.yaml --recording REC --out DIR`` (REC: a recording
CSV or a rosbag2 MCAP bag) simulates the
twin with the recording's inputs, locates and diagnoses the residuals, fits the effect
library on a training window, adopts what improves the held-out window, and writes
``DIR/report.json``, ``DIR/report.md`` (PNG plots beside it), ``DIR/diagnosis.rrd`` (rerun)
and, when an effect is adopted, ``DIR/twin_augmented.yaml``. With ``--calibrate`` the twin's
existing parameters are fitted first (``DIR/twin_calibrated.yaml``; the report separates
mis-calibrated parameters from missing mechanisms); physics outside the vocabulary is
answered ``unnamed`` with a sparse formula. The independent tasks (channel analyses, candidate
screening and fits, out-of-vocabulary fits) run on a local process pool of ``--jobs`` processes
(default: the cores) or a Dask cluster (``--engine dask [--address tcp://HOST:8786]``); the
answer is the same on every engine (docs/distributed.md).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

from thermal_twin.calibration import CalibrationError
from thermal_twin.calibration_bounds import CalibrationSpecError
from thermal_twin.machine_schema import MachineSpecError, load_machine, save_machine
from thermal_twin.mismatch_diagnosis import DiagnosisError, diagnose
from thermal_twin.mismatch_effects import EFFECTS
from thermal_twin.mismatch_report import write_report
from thermal_twin.column_mapping import (MappingError, empty_columns, name_mismatches, parse_mapping,
                                        read_real_recording)
from thermal_comp_common.engine_options import add_engine_arguments, engine_from_args
from thermal_comp_common.recording_csv import RecordingError
from thermal_comp_common.task_engine import TaskEngineError, default_workers


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp diagnose", description=__doc__.split("\n\n")[0])
    p.add_argument("--twin", required=True, help="machine YAML file or preset name (e.g. spindle-stand)")
    p.add_argument("--recording", required=True,
                   help="recording CSV in the twin's CSV format (time_s, inputs, <sensor>_c, error "
                        "channels), or a rosbag2 MCAP bag (folder or .mcap file)")
    p.add_argument("--map", action="append", default=[], metavar="OLD=NEW|NAME*FACTOR",
                   help="rename a recording column to the twin's name, or scale one (e.g. ch3_um*-1 "
                        "flips its sign); repeatable")
    p.add_argument("--map-file", help="YAML column mapping {columns: {old: new}, scale: {name: factor}}")
    p.add_argument("--temperatures-topic", default="temperatures",
                   help="bag only: TemperatureArray topic of the sensor readings (default temperatures)")
    p.add_argument("--errors-topic", default="errors/ground_truth",
                   help="bag only: ThermalErrors topic of the error channels (default errors/ground_truth; "
                        "errors/measured for probed errors)")
    p.add_argument("--out", required=True, help="output directory (must be new or empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty --out")
    p.add_argument("--holdout-fraction", type=float, default=1 / 3,
                   help="last fraction of the recording kept out of every fit (default 1/3)")
    p.add_argument("--max-effects", type=int, default=2, help="at most this many effects adopted (default 2)")
    p.add_argument("--min-improvement", type=float, default=5.0,
                   help="held-out improvement in %% an effect needs to be adopted (default 5)")
    p.add_argument("--effects", default=",".join(e for e in EFFECTS if e != "none"),
                   help="comma-separated subset of the effect vocabulary to try")
    p.add_argument("--start-hour", type=float, default=0.0,
                   help="clock hour at time_s = 0, for the day/night regimes (default 0)")
    p.add_argument("--max-lag-h", type=float, default=6.0, help="cross-correlation lags up to this (h)")
    p.add_argument("--calibrate", action="store_true",
                   help="fit the twin's existing parameters first; effects must beat that on held-out data")
    p.add_argument("--bounds", help="with --calibrate: YAML calibration section (kinds, parameters)")
    p.add_argument("--max-nfev", type=int, default=20, help="with --calibrate: optimiser iterations (default 20)")
    p.add_argument("--no-unnamed", action="store_true", help="do not fit an out-of-vocabulary discrepancy")
    p.add_argument("--no-rerun", action="store_true", help="do not write the rerun recording")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_engine_arguments(p, default_workers(), "channel analyses and candidate fits")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
                                  args.temperatures_topic, args.errors_topic)
        rec.warnings += name_mismatches(machine, rec)
        empty = empty_columns(rec)
        if empty:     # named, never dropped silently
            rec.warnings.append(f"columns without any value (not used): {', '.join(empty)}")
        for w in rec.warnings:
            print(f"warning: {w}", file=sys.stderr)
        section = None
        if args.bounds:
            import yaml
            raw = yaml.safe_load(pathlib.Path(args.bounds).read_text())
            section = (raw or {}).get("calibration", raw)
        d = diagnose(machine, rec, holdout_fraction=args.holdout_fraction, max_effects=args.max_effects,
                     min_improvement_pct=args.min_improvement, start_hour=args.start_hour,
                     effects=effects, max_lag_s=args.max_lag_h * 3600.0, progress=not args.quiet,
                     calibrate=args.calibrate, calibration_section=section, calibration_nfev=args.max_nfev,
                     unnamed=not args.no_unnamed, engine=engine)
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
    sel = d.report["selected"]
    for u in d.report.get("unnamed", []):
        print(f"unnamed (not in the vocabulary; nearest word {u['nearest_vocabulary_word']}): {u['formula']}; "
              f"held-out improvement {u['holdout_improvement_pct']:.1f} %")
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


if __name__ == "__main__":
    sys.exit(main())
