"""Simulate a machine cell offline and write a recording CSV (`thermal-comp sim`).

Example: thermal-comp sim --machine nmv5000 --scenario talc-178h-dry --csv out.csv
Columns: time_s, the machine's inputs, <sensor>_c readings, true error components
(docs/twin.md).
"""
from __future__ import annotations

import argparse
import sys

from thermal_twin.inputs_timeline import TimelineError
from thermal_twin.machine_schema import MachineSpecError, load_machine
from thermal_twin.presets import preset_names
from thermal_comp_common.recording_csv import RecordingError, write_recording_csv
from thermal_twin.scenarios import SCENARIOS, ScenarioError, make_timeline
from thermal_twin.simulate import simulate


def build_parser() -> argparse.ArgumentParser:
    scen = "; ".join(f"{n} ({', '.join(b.replace('_', '-') for b in s.builders)})"
                     for n, s in sorted(SCENARIOS.items()))
    p = argparse.ArgumentParser(
        prog="thermal-comp sim", description=__doc__.splitlines()[0],
        epilog=f"presets: {', '.join(preset_names())}. scenarios (machines): {scen}.")
    p.add_argument("--machine", required=True,
                   help="preset name (nmv5000, swiss-lathe, spindle-stand, fe-three-body) or a machine YAML file")
    p.add_argument("--scenario", required=True, help="scenario name (see below)")
    p.add_argument("--hours", type=float, default=None, help="duration in hours (default: the scenario's)")
    p.add_argument("--seed", type=int, default=0, help="random seed of scenario and sensor noise (default 0)")
    p.add_argument("--step", type=float, default=None, help="time step in s (default: the scenario's)")
    p.add_argument("--csv", required=True, help="output recording CSV")
    p.add_argument("--plot", default=None, help="also write a PNG overview (inputs, readings, errors)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        machine = load_machine(args.machine)
        # a machine file is matched to scenarios by its name (e.g. an edited nmv5000 copy)
        timeline = make_timeline(machine.name, args.scenario, hours=args.hours, seed=args.seed,
                                 step_s=args.step)
    except (MachineSpecError, ScenarioError, TimelineError) as exc:
        print(f"thermal-comp sim: {exc}", file=sys.stderr)
        return 2
    from tqdm import tqdm
    with tqdm(total=len(timeline), unit="step", desc=f"{machine.name}/{args.scenario}",
              disable=args.quiet, file=sys.stderr) as bar:
        try:
            result = simulate(machine, timeline, seed=args.seed, progress=bar.update)
        except (TimelineError, MachineSpecError) as exc:
            print(f"thermal-comp sim: {exc}", file=sys.stderr)
            return 2
    try:
        write_recording_csv(args.csv, result.time_s, result.columns())
    except (OSError, RecordingError) as exc:
        print(f"thermal-comp sim: cannot write {args.csv}: {exc}", file=sys.stderr)
        return 1
    if args.plot:
        from thermal_twin.recording_plot import plot_recording
        plot_recording(result.to_recording(), args.plot, title=f"{machine.name} / {args.scenario} (seed {args.seed})")
    if not args.quiet:
        print(f"wrote {args.csv}: {len(result.time_s)} rows, "
              f"{len(result.sensors)} sensors, errors {', '.join(result.errors)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
