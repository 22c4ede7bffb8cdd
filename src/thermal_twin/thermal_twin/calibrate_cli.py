"""Calibrate a twin on a recording: ``thermal-comp calibrate --twin M --recording REC --out DIR``.

Fits the twin's existing parameters (ranges from the machine's ``calibration`` section or
``--bounds``) on the training window, scores the held-out rest, and writes
``DIR/twin_calibrated.yaml``, ``DIR/report.md``, ``DIR/report.json`` and PNG plots. The
Jacobian's finite-difference columns can run on a local process pool (``--jobs N``) or a Dask
cluster (``--engine dask [--address tcp://HOST:8786]``); the answer is the same on every engine
(docs/distributed.md). Default serial: a Jacobian is ~40 twin runs of a few ms, and a pool per
Jacobian cost more CPU than it saved on FL_THERMAL (docs/diagnose.md, Speed).
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import yaml

from thermal_twin.calibrate_report import plot_input_estimate, write_report
from thermal_twin.calibration import CalibrationError, calibrate, pick_channels
from thermal_twin.input_estimation import InputEstimationError, fill_missing_inputs, missing_inputs
from thermal_twin.calibration_bounds import CalibrationSpecError
from thermal_twin.machine_schema import MachineSpecError, load_machine, save_machine
from thermal_twin.column_mapping import (MappingError, empty_columns, name_mismatches, parse_mapping,
                                        read_real_recording)
from thermal_comp_common.engine_options import add_engine_arguments, engine_from_args
from thermal_comp_common.recording_csv import RecordingError
from thermal_comp_common.task_engine import TaskEngineError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="thermal-comp calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("--twin", required=True, help="machine YAML file or preset name (e.g. spindle-stand)")
    p.add_argument("--recording", required=True, help="recording CSV or rosbag2 MCAP bag")
    p.add_argument("--out", required=True, help="output directory (must be new or empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty --out")
    p.add_argument("--bounds", help="YAML file with a calibration section (kinds, parameters); "
                                    "replaces the machine's own")
    p.add_argument("--holdout-fraction", type=float, default=1 / 3,
                   help="last fraction of the recording kept out of the fit (default 1/3)")
    p.add_argument("--max-nfev", type=int, default=20,
                   help="at most this many optimiser iterations (default 20)")
    p.add_argument("--block-min", type=float, default=30.0,
                   help="block length of an input estimated from the temperatures (min, default 30)")
    p.add_argument("--map", action="append", default=[], metavar="OLD=NEW|NAME*FACTOR",
                   help="rename a recording column to the twin's name, or scale one (e.g. ch3_um*-1 "
                        "flips its sign); repeatable")
    p.add_argument("--map-file", help="YAML column mapping {columns: {old: new}, scale: {name: factor}}")
    p.add_argument("--temperatures-topic", default="temperatures", help="bag only")
    p.add_argument("--errors-topic", default="errors/ground_truth", help="bag only")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_engine_arguments(p, 1, "Jacobian columns")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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


if __name__ == "__main__":
    sys.exit(main())
