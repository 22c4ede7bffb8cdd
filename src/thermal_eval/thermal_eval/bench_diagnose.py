"""Benchmark of the mismatch finder (`thermal-comp bench diagnose`): wall time of one diagnosis.

The case the issue names: a 46 h recording with 16 sensors and 5 displacement channels,
i.e. the ``spindle-stand`` twin on its ``fl-thermal-programme`` (15 s steps, 11,100 rows)
with a concealed heat source in the headstock (80 W at full speed), diagnosed against the
unmodified twin. Figures: wall and CPU time of the whole diagnosis (simulation, statistics,
locating, screening and fitting every candidate, two rounds), the number of twin
evaluations, and whether the concealed effect was found. ``args.quick`` shortens the
recording to 12 h.
"""
from __future__ import annotations

import argparse
import time

from thermal_twin.machine_schema import load_machine
from thermal_eval.mismatch_concealed import find_candidate
from thermal_twin.mismatch_diagnosis import diagnose
from thermal_twin.scenarios import make_timeline
from thermal_twin.simulate import simulate

HIDDEN = ("heat_source:headstock:spindle_rpm", (80.0, 1.2))


def run(args: argparse.Namespace | None = None) -> dict:
    quick = bool(getattr(args, "quick", False)) if args is not None else False
    hours = 12.0 if quick else None
    spec = load_machine("spindle-stand").to_dict()
    tl = make_timeline("spindle-stand", "fl-thermal-programme", hours=hours, seed=0)
    true = find_candidate(spec, tl, HIDDEN[0]).apply(spec, HIDDEN[1])
    rec = simulate(true, tl, seed=0).to_recording()
    t0, c0 = time.perf_counter(), time.process_time()
    d = diagnose(spec, rec)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rep = d.report
    sel = rep["selected"]
    found = sel != "none" and f"{sel[0]['effect']}:{sel[0]['target']}:{sel[0]['driver']}" == HIDDEN[0]
    key = "diagnose.spindle-stand.fl-thermal-programme"
    figures = {
        f"{key}.recording_hours": round(float(rec.time_s[-1] - rec.time_s[0]) / 3600.0, 2),
        f"{key}.rows": len(rec),
        f"{key}.sensors": len(rec.sensors),
        f"{key}.error_channels": len(rec.errors),
        f"{key}.wall_s": round(wall, 2),
        f"{key}.cpu_s": round(cpu, 2),
        f"{key}.twin_evaluations": rep["simulations"],
        f"{key}.hypotheses_fitted": len(rep["hypotheses"]),
        f"{key}.concealed_effect_found": bool(found),
    }
    for k, v in figures.items():
        print(f"{k}: {v}")
    return figures


if __name__ == "__main__":
    run()
