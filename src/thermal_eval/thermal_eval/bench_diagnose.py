"""Benchmark of the mismatch finder (`thermal-comp bench diagnose`): wall time of one diagnosis.

The case the issue names: a 46 h recording with 16 sensors and 5 displacement channels,
i.e. the ``spindle-stand`` twin on its ``fl-thermal-programme`` (15 s steps, 11,100 rows)
with a concealed heat source in the headstock (80 W at full speed), diagnosed against the
unmodified twin. Figures: wall and CPU time of the whole diagnosis (simulation, statistics,
locating, screening and fitting every candidate, two rounds), the number of twin
evaluations, and whether the concealed effect was found. ``args.quick`` shortens the
recording to 12 h and skips the suite.

Then the broadened concealed-effect suite (:mod:`thermal_eval.diagnose_suite`): true effect
first (%), exact target (%), extra adopted effects per ten cases, ``none`` on the no-effect
cases, ``unnamed`` on the out-of-vocabulary cases with their held-out improvement, the
diagnosis wall times, two diagnoses with ``calibrate=True`` (calibration and diagnosis wall
time), and the twin's simulated hours per second of the finder's evaluation.

Then, when the FL_THERMAL CSV is available (``$THERMAL_COMP_SHARED``), the calibration of
the ``spindle-stand`` preset on it (46 h, 16 sensors, 5 channels; the preset's calibration
section): wall and CPU time, twin evaluations, simulated hours per second. Every timing
line carries the machine's load average, because the 2 cores are shared.
"""
from __future__ import annotations

import argparse
import os
import time

from thermal_eval import diagnose_suite
from thermal_twin.machine_schema import load_machine
from thermal_twin.mismatch_fit import FitProblem
from thermal_twin.mismatch_twin_eval import single_threaded_blas
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
    figures[f"{key}.twin_simulated_h_per_s"] = round(twin_hours_per_s(spec, rec), 0)
    figures[f"{key}.load_average_1min"] = round(os.getloadavg()[0], 1)
    for k, v in figures.items():
        print(f"{k}: {v}", flush=True)
    figures.update(fl_thermal_calibration())
    if not quick:
        figures.update(run_suite(spec, rec))
    return figures


def fl_thermal_calibration() -> dict:
    """Calibration of spindle-stand on the real FL_THERMAL recording (skipped, with a line
    saying so, when the CSV is not available)."""
    from thermal_eval.fl_thermal_data import FlThermalError, default_csv_path
    from thermal_twin.calibration import calibrate
    from thermal_twin.column_mapping import parse_mapping, read_real_recording
    key = "diagnose.calibrate.fl_thermal"
    try:
        csv = default_csv_path()
    except FlThermalError as exc:
        print(f"{key}: skipped ({exc})", flush=True)
        return {}
    rec = read_real_recording(str(csv), parse_mapping(None, []), "temperatures", "errors/ground_truth")
    t0, c0 = time.perf_counter(), time.process_time()
    r = calibrate("spindle-stand", rec)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    figures = {f"{key}.free_parameters": len(r.estimates), f"{key}.channels": len(r.channels),
               f"{key}.wall_s": round(wall, 2), f"{key}.cpu_s": round(cpu, 2),
               f"{key}.twin_evaluations": r.n_evals,
               f"{key}.twin_simulated_h_per_s": round(r.simulated_h / max(wall, 1e-9), 0),
               f"{key}.cost_reduction_pct": round(100.0 * (1.0 - r.cost_after / max(r.cost_before, 1e-300)), 1),
               f"{key}.status": r.status, f"{key}.load_average_1min": round(os.getloadavg()[0], 1)}
    for k, v in figures.items():
        print(f"{k}: {v}", flush=True)
    return figures


def twin_hours_per_s(spec: dict, rec, repeats: int = 5) -> float:
    """Simulated hours per wall second of the finder's noise-free twin evaluation."""
    prob = FitProblem(rec, list(rec.sensors)[:1], len(rec) // 2)
    with single_threaded_blas():          # as inside diagnose and calibrate
        t0 = time.perf_counter()
        for _ in range(repeats):
            prob.outputs(spec)
        wall = time.perf_counter() - t0
    return repeats * float(rec.time_s[-1] - rec.time_s[0]) / 3600.0 / wall


def run_suite(spec_stand: dict, rec_stand) -> dict:
    key = "diagnose.suite"
    mm = diagnose_suite.mini_mill()
    outcomes = []
    for case in diagnose_suite.SUITE:
        o = diagnose_suite.run_case(mm, case)
        outcomes.append(o)
        print(f"  {o['case']}: answer {o['answer']} {o['selected'] or ''}"
              f"{' ' + '; '.join(u['formula'] + ' (' + format(u['holdout_improvement_pct'], '.1f') + ' %)' for u in o['unnamed']) if o['unnamed'] else ''}"
              f" [{o['wall_s']:.1f} s]", flush=True)
    figures = {f"{key}.{k}": (round(v, 2) if isinstance(v, float) else v)
               for k, v in diagnose_suite.score(outcomes).items()}
    for case in (diagnose_suite.SUITE[0], diagnose_suite.SUITE[22]):
        o = diagnose_suite.run_case(mm, case, calibrate=True)
        figures[f"{key}.calibrate_first.{o['case']}.answer"] = o["answer"]
        figures[f"{key}.calibrate_first.{o['case']}.calibration_wall_s"] = round(o["calibration_wall_s"], 2)
        figures[f"{key}.calibrate_first.{o['case']}.diagnosis_wall_s"] = round(o["wall_s"], 2)
    rec_mm, _ = diagnose_suite.concealed_recording(mm, (), hours=48.0, step_s=300.0, seed=1)
    figures[f"{key}.twin_simulated_h_per_s.mini_mill_300s"] = round(twin_hours_per_s(mm, rec_mm), 0)
    figures[f"{key}.twin_simulated_h_per_s.spindle_stand_15s"] = round(twin_hours_per_s(spec_stand, rec_stand), 0)
    for k, v in figures.items():
        print(f"{k}: {v}", flush=True)
    return figures


if __name__ == "__main__":
    run()
