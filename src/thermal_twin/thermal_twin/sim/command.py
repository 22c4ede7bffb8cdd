"""The work of ``thermal-comp sim`` (:mod:`thermal_twin.sim.cli` parses the arguments):
simulate the machine on the scenario and write the recording CSV (and a PNG overview)."""
from __future__ import annotations

import sys

from thermal_comp_common import plain_output
from thermal_twin.sim.inputs_timeline import TimelineError
from thermal_twin.machine.schema import MachineSpecError, load_machine
from thermal_comp_common.recording_csv import RecordingError, write_recording_csv
from thermal_twin.sim.scenarios import ScenarioError, make_timeline
from thermal_twin.sim.simulate import simulate


def run(args) -> int:
    """Simulate as the parsed arguments say; the exit code (0 written, 1 cannot write, 2 bad arguments)."""
    try:
        machine = load_machine(args.machine)
        # a machine file is matched to scenarios by its name (e.g. an edited nmv5000 copy)
        timeline = make_timeline(machine.name, args.scenario, hours=args.hours, seed=args.seed,
                                 step_s=args.step)
    except (MachineSpecError, ScenarioError, TimelineError) as exc:
        print(f"thermal-comp sim: {exc}", file=sys.stderr)
        return 2
    bar = None if args.quiet else plain_output.progress(len(timeline), f"{machine.name}/{args.scenario}", "step")
    try:
        result = simulate(machine, timeline, seed=args.seed, progress=bar.advance if bar else None)
    except (TimelineError, MachineSpecError) as exc:
        print(f"thermal-comp sim: {exc}", file=sys.stderr)
        return 2
    finally:
        if bar is not None:
            bar.close()
    try:
        write_recording_csv(args.csv, result.time_s, result.columns())
    except (OSError, RecordingError) as exc:
        print(f"thermal-comp sim: cannot write {args.csv}: {exc}", file=sys.stderr)
        return 1
    if args.plot:
        from thermal_twin.calibrate.recording_plot import plot_recording  # matplotlib: only with --plot
        plot_recording(result.to_recording(), args.plot, title=f"{machine.name} / {args.scenario} (seed {args.seed})")
    if not args.quiet:
        print(f"wrote {args.csv}: {len(result.time_s)} rows, "
              f"{len(result.sensors)} sensors, errors {', '.join(result.errors)}", file=sys.stderr)
    return 0
