"""Benchmark of the twin (`thermal-comp bench twin`): simulated hours per wall second.

For each preset one representative scenario is simulated at the scenario's own step; the
wall time includes building the network and every matrix exponential (cached per
conductance regime within the run). Pass ``--quick`` semantics via ``args.quick`` to cap
runs at 24 simulated hours.
"""
from __future__ import annotations

import argparse
import time

from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

CASES = {  # preset -> (scenario, hours)
    "nmv5000": ("talc-178h-dry", 178.0),
    "swiss-lathe": ("lathe-random-speed", 70.0),
    "spindle-stand": ("fl-thermal-programme", None),
    "fe-three-body": ("fe-two-source", 48.0),
}


def run(args: argparse.Namespace | None = None) -> dict:
    quick = bool(getattr(args, "quick", False)) if args is not None else False
    figures: dict[str, float] = {}
    for machine, (scenario, hours) in CASES.items():
        if quick and hours:
            hours = min(hours, 24.0)
        tl = make_timeline(machine, scenario, hours=hours, seed=0)
        sim_h = (tl.time_s[-1] - tl.time_s[0]) / 3600.0
        t0 = time.perf_counter()
        r = simulate(machine, tl, seed=0)
        wall = time.perf_counter() - t0
        key = f"twin.{machine}.{scenario}"
        figures[f"{key}.simulated_hours_per_wall_s"] = round(sim_h / wall, 1)
        figures[f"{key}.steps"] = len(tl)
        figures[f"{key}.step_s"] = float(tl.time_s[1] - tl.time_s[0])
        figures[f"{key}.wall_s"] = round(wall, 3)
        figures[f"{key}.nodes"] = len(r.machine.nodes)
    for k, v in figures.items():
        print(f"{k}: {v}")
    return figures


if __name__ == "__main__":
    run(None)
