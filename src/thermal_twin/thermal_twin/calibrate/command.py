"""The work of ``thermal-comp calibrate`` (:mod:`thermal_twin.calibrate.cli` parses the arguments):
fit the twin on the recording and write the calibrated twin, the report and its plots."""
from __future__ import annotations

import pathlib
import sys

import yaml

from thermal_twin.calibrate.report import plot_input_estimate, write_report
from thermal_twin.calibrate.fit import CalibrationError, calibrate, pick_channels
from thermal_twin.calibrate.input_estimation import InputEstimationError, fill_missing_inputs, missing_inputs
from thermal_twin.calibrate.bounds import CalibrationSpecError
from thermal_twin.machine.schema import MachineSpecError, load_machine, save_machine
from thermal_twin.calibrate.column_mapping import (MappingError, empty_columns, name_mismatches, parse_mapping,
                                        read_real_recording)
from thermal_comp_common.runtime.engine_options import engine_from_args
from thermal_comp_common.recording_csv import RecordingError
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
        rec = read_real_recording(args.recording, parse_mapping(args.map_file, args.map),
                                  args.temperatures_topic, args.errors_topic)
        notes = list(rec.warnings) + name_mismatches(machine, rec)
        empty = empty_columns(rec)
        if empty:
            notes.append(f"columns without any value (not used): {', '.join(empty)}")
        say = None if args.quiet else (lambda s: print(s, file=sys.stderr))
        estimates = []
        if missing_inputs(machine, rec):
            chans, _ = pick_channels(machine, rec)
            rec, estimates, found = fill_missing_inputs(machine, rec, chans, block_s=args.block_min * 60.0)
            notes = found + notes
        r = calibrate(machine, rec, holdout_fraction=args.holdout_fraction, section=section,
                      max_nfev=args.max_nfev, progress=say, engine=engine)
    except (MachineSpecError, MappingError, CalibrationSpecError, RecordingError, CalibrationError,
            InputEstimationError, TaskEngineError, ValueError, OSError) as exc:
        print(f"thermal-comp calibrate: {exc}", file=sys.stderr)
        return 1
    out.mkdir(parents=True, exist_ok=True)
    save_machine(r.spec, out / "twin_calibrated.yaml")
    paths = write_report(r, out, machine.source_path or machine.name, rec.source, notes,
                         input_estimates=[e.as_dict() for e in estimates])
    for e in estimates:
        paths[f"input_{e.input}"] = out / f"input_estimate_{e.input}.png"
        plot_input_estimate(e, rec.time_s, paths[f"input_{e.input}"])
    rate = r.simulated_h / max(r.wall_s, 1e-9)
    print(f"calibrated {len(r.estimates)} parameters on {len(r.channels)} channels in {r.wall_s:.1f} s "
          f"({r.n_evals} twin evaluations, {rate:.0f} simulated h/s); cost {r.cost_before:.4g} -> "
          f"{r.cost_after:.4g} ({r.status})")
    for c, v in r.channel_table().items():
        print(f"  {c:10s} held-out RMSE {v['holdout_rmse_before']:.4g} -> {v['holdout_rmse_after']:.4g}")
    unid = [e.param.name for e in r.estimates if any(f.startswith("not identified") for f in e.flags)]
    print(f"not identified by this recording: {len(unid)} of {len(r.estimates)}; "
          f"correlated pairs: {len(r.correlated)}")
    for n in notes:
        print(f"note: {n}")
    print("report: " + ", ".join(str(p) for p in [out / "twin_calibrated.yaml", *paths.values()]))
    return 0
