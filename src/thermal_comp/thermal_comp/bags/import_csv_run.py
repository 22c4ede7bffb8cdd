"""The work of ``thermal-comp import-csv`` (:mod:`thermal_comp.bags.import_csv_cli` parses the arguments):
a recording CSV into a rosbag2 MCAP bag (thermal_comp_common.bags.csv_to_bag)."""
from __future__ import annotations

import sys


from thermal_comp_common.bags.writer import BagWriteError, remove_bag_folder
from thermal_comp_common.bags.csv_to_bag import CsvImportError, recording_to_bag
from thermal_comp_common.plain_output import progress
from thermal_comp_common.recording_csv import RecordingError, read_recording_csv


def run(args) -> int:
    """Import as the parsed arguments say; the exit code (0 imported, 2 bad input or OUT exists)."""
    bar = None
    try:
        if args.force:
            remove_bag_folder(args.out)
        rec = read_recording_csv(args.csv, sample_period_s=args.sample_period_s)
        if not args.no_progress:
            lo, hi = args.rows
            total = len(range(lo, len(rec) if hi is None else min(hi, len(rec)), max(args.every, 1)))
            bar = progress(total, "import-csv", "row")
        res = recording_to_bag(rec, args.out, temperatures_topic=args.temperatures_topic,
                         errors_as=args.errors, error_model_kind=args.error_model_kind,
                         namespace=args.namespace, start_s=args.start, every=args.every,
                         rows=args.rows, strict=args.strict,
                         progress=None if bar is None else bar.advance)
    except (RecordingError, CsvImportError, BagWriteError) as exc:
        print(f"thermal-comp import-csv: {exc}", file=sys.stderr)
        return 2
    finally:
        if bar is not None:
            bar.close()
    for w in res.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if res.unmapped:
        print(f"note: input column(s) {', '.join(res.unmapped)} have no MachineState field; "
              f"not imported", file=sys.stderr)
    print(f"{res.bag}: {res.rows} rows -> " + ", ".join(f"{t} {n}" for t, n in res.messages.items()))
    return 0
