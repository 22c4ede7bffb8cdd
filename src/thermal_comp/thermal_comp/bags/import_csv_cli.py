"""Import a recording CSV (the twin's CSV, shared/data/fl_thermal) into a rosbag2 MCAP bag."""
from __future__ import annotations

import argparse
import sys

from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def _rows(text: str) -> tuple[int, int | None]:
    lo, sep, hi = text.partition(":")
    try:
        return (int(lo) if lo else 0), (int(hi) if hi else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--rows {text!r}: expected START:STOP (row numbers)") from None


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="thermal-comp import-csv", description=__doc__,
        epilog="Columns (thermal_comp_common.recording_csv): <id>_c -> TemperatureArray sensor <id>; E_* and "
               "<name>_um -> ThermalErrors components; machine inputs -> MachineState as machine_sim "
               "names them (<a>_speed_rpm rotary axis A, other *_rpm spindles, *_w drive powers, "
               "coolant_on/oil_on, coolant_temp_degc/oil_temp_degc, door_open). Example: "
               "thermal-comp import-csv ../shared/data/fl_thermal/fl_thermal.csv out/fl --errors measured --every 4. "
               "Exit codes: 0 imported, 2 bad arguments, unreadable CSV (one line naming file, line "
               "and column) or OUT exists (without --force).")
    ap.add_argument("csv", metavar="CSV", help="recording CSV file")
    add_sample_period_argument(ap)
    ap.add_argument("out", metavar="OUT", help="bag folder to create (must not exist, see --force)")
    ap.add_argument("--force", action="store_true",
                    help="replace an existing bag folder OUT (only a bag or an empty folder)")
    ap.add_argument("--errors", choices=("ground_truth", "measured"), default="ground_truth",
                    help="publish the error columns as the twin's ground truth (default) or as "
                         "measured errors (SOURCE_MEASURED on errors/measured)")
    ap.add_argument("--error-model-kind", default=None,
                    help="model_kind of the error messages (default 'twin' / 'recording')")
    ap.add_argument("--temperatures-topic", default="temperatures",
                    help="relative topic of the temperatures (default temperatures; the twin's raw "
                         "readings are twin/sensor_readings)")
    ap.add_argument("--namespace", default="", help="cell namespace prefixed to every topic")
    ap.add_argument("--start", type=float, default=0.0, metavar="S",
                    help="stamp of time_s = 0, in seconds (default 0: simulated time)")
    ap.add_argument("--every", type=int, default=1, metavar="N", help="keep every N-th row")
    ap.add_argument("--rows", type=_rows, default=(0, None), metavar="START:STOP",
                    help="import only these rows (0-based, STOP exclusive)")
    ap.add_argument("--strict", action="store_true",
                    help="fail if an input column cannot be represented in MachineState")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    return run_parsed("thermal_comp.bags.import_csv_run:run", args)


if __name__ == "__main__":
    raise SystemExit(main())
