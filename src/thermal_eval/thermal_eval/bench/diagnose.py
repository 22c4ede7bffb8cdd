"""Benchmark of the mismatch finder (`thermal-comp bench diagnose`): wall time of one diagnosis.

The reference case: a 46 h recording with 16 sensors and 5 displacement channels,
i.e. the ``spindle-stand`` twin on its ``fl-thermal-programme`` (15 s steps, 11,100 rows)
with a concealed heat source in the headstock (80 W at full speed), diagnosed against the
unmodified twin. Figures: wall and CPU time of the whole diagnosis (simulation, statistics,
locating, screening and fitting every candidate, two rounds), the number of twin
evaluations, and whether the concealed effect was found. ``args.quick`` shortens the
recording to 12 h and skips the suite; ``--suite-only`` runs only the suite.

Then the broadened concealed-effect suite (:mod:`thermal_eval.diagnose.suite`): true effect
first (%), exact target (%), extra adopted effects per ten cases, ``none`` on the no-effect
cases, ``unnamed`` on the out-of-vocabulary cases with their held-out improvement, the
concealed conduction paths named exactly, the changed existing links found by the
calibration (``mis-calibrated``), the diagnosis wall times and load average, two diagnoses with ``calibrate=True`` (calibration and diagnosis wall
time), and the twin's simulated hours per second of the finder's evaluation.

Then, when the FL_THERMAL CSV is available (``$THERMAL_COMP_SHARED``), the diagnosis of the
``spindle-stand`` preset against the real recording (what ``thermal-comp diagnose --twin
spindle-stand --recording fl_thermal.csv`` runs) serially and on a local pool of 2 processes
(wall, CPU of the process and its workers, twin evaluations, the twin's simulated hours per
second on this recording, and whether the two reports are identical), and the calibration of
``spindle-stand`` on it (46 h, 16 sensors, 5 channels; the preset's calibration section) on
the same two engines. Every timing line carries the machine's load average, because the 2
cores are shared.
"""
from __future__ import annotations

import argparse
import os
import resource
import time

from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_eval.diagnose import random_bench
from thermal_eval.diagnose import suite as diagnose_suite
from thermal_twin.calibrate.column_mapping import parse_mapping, read_real_recording
from thermal_twin.calibrate.fit import calibrate
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.fit import FitProblem
from thermal_eval.diagnose.concealed import find_candidate
from thermal_eval.fl_thermal.data import FlThermalError, default_csv_path
from thermal_twin.diagnose.diagnosis import diagnose
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

HIDDEN = ("heat_source:headstock:spindle_rpm", (80.0, 1.2))


def run(args: argparse.Namespace | None = None) -> dict:
    quick = bool(getattr(args, "quick", False)) if args is not None else False
    if "--random" in (getattr(args, "extra", None) or []):    # drawn cases: diagnose/random_bench.py
        return random_bench.run(args)
    if "--suite-only" in (getattr(args, "extra", None) or []):
        return run_suite(None, None)
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
    figures.update(fl_thermal_diagnosis())
    figures.update(fl_thermal_calibration())
    if not quick:
        figures.update(run_suite(spec, rec))
    return figures


def _timed(fn):
    """(result, wall s, CPU s of this process and of the workers it joined)."""
    t0, c0 = time.perf_counter(), time.process_time()
    ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = fn()
    ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = time.process_time() - c0 + (ch1.ru_utime + ch1.ru_stime) - (ch0.ru_utime + ch0.ru_stime)
    return out, time.perf_counter() - t0, cpu


def _fl_thermal_recording():
    """The real FL_THERMAL recording, or None (with a line saying why) when it is absent."""
    try:
        csv = default_csv_path()
    except FlThermalError as exc:
        print(f"diagnose.fl_thermal: skipped ({exc})", flush=True)
        return None
    return read_real_recording(str(csv), parse_mapping(None, []), "temperatures", "errors/ground_truth")


def _timeless(x):
    if isinstance(x, dict):
        return {k: _timeless(v) for k, v in x.items() if k not in ("wall_s", "simulated_h_per_s")}
    if isinstance(x, list):
        return [_timeless(v) for v in x]
    return x


ENGINES = (("serial", EngineSpec("local", workers=1)), ("local2", EngineSpec("local", workers=2)))


def fl_thermal_diagnosis() -> dict:
    """``diagnose --twin spindle-stand`` on the real FL_THERMAL recording, serial and on 2
    local processes: wall, CPU (with the workers'), twin evaluations and twin h/s."""
    rec = _fl_thermal_recording()
    if rec is None:
        return {}
    key = "diagnose.fl_thermal.spindle-stand"
    figures: dict = {f"{key}.rows": len(rec)}
    reports = []
    for name, engine in ENGINES:
        d, wall, cpu = _timed(lambda: diagnose("spindle-stand", rec, engine=engine))
        reports.append(_timeless(d.report))
        figures.update({f"{key}.{name}.wall_s": round(wall, 2), f"{key}.{name}.cpu_s": round(cpu, 2),
                        f"{key}.{name}.load_average_1min": round(os.getloadavg()[0], 1)})
        figures[f"{key}.twin_evaluations"] = d.report["simulations"]
        figures[f"{key}.answer"] = d.report["answer"]
    figures[f"{key}.identical_reports"] = reports[0] == reports[1]
    figures[f"{key}.twin_simulated_h_per_s"] = round(
        twin_hours_per_s(load_machine("spindle-stand").to_dict(), rec), 0)
    for k, v in figures.items():
        print(f"{k}: {v}", flush=True)
    return figures


def fl_thermal_calibration() -> dict:
    """Calibration of spindle-stand on the real FL_THERMAL recording, serial and on 2 local
    processes (skipped, with a line saying so, when the CSV is not available)."""
    rec = _fl_thermal_recording()
    if rec is None:
        return {}
    key = "diagnose.calibrate.fl_thermal"
    figures: dict = {}
    answers = []
    for name, engine in ENGINES:
        r, wall, cpu = _timed(lambda: calibrate("spindle-stand", rec, engine=engine))
        answers.append(([e.as_dict() for e in r.estimates], r.cost_after))
        figures.update({f"{key}.{name}.wall_s": round(wall, 2), f"{key}.{name}.cpu_s": round(cpu, 2),
                        f"{key}.{name}.twin_simulated_h_per_s": round(r.simulated_h / max(wall, 1e-9), 0),
                        f"{key}.{name}.load_average_1min": round(os.getloadavg()[0], 1)})
    figures.update({f"{key}.free_parameters": len(r.estimates), f"{key}.channels": len(r.channels),
                    f"{key}.twin_evaluations": r.n_evals,
                    f"{key}.cost_reduction_pct": round(100.0 * (1.0 - r.cost_after / max(r.cost_before, 1e-300)), 1),
                    f"{key}.status": r.status, f"{key}.identical_estimates": answers[0] == answers[1]})
    for k, v in figures.items():
        print(f"{k}: {v}", flush=True)
    return figures


def twin_hours_per_s(spec: dict, rec, repeats: int = 5) -> float:
    """Simulated hours per wall second of the finder's noise-free twin evaluation."""
    prob = FitProblem(rec, list(rec.sensors)[:1], len(rec) // 2)
    with single_thread_blas():          # as inside diagnose and calibrate
        t0 = time.perf_counter()
        for _ in range(repeats):
            prob.outputs(spec)
        wall = time.perf_counter() - t0
    return repeats * float(rec.time_s[-1] - rec.time_s[0]) / 3600.0 / wall


def _case_line(o: dict) -> str:
    unnamed = "; ".join(f"{u['formula']} ({u['holdout_improvement_pct']:.1f} %)" for u in o["unnamed"])
    moved = ", ".join(f"{n} -> {v:.4g}" for n, v in o["moved"][:2])
    return (f"  {o['case']}: answer {o['answer']} {o['selected'] or ''}{' ' + unnamed if unnamed else ''}"
            f"{' moved ' + moved if moved else ''} [{o['wall_s']:.1f} s, load {os.getloadavg()[0]:.1f}]")


def run_suite(spec_stand: dict | None, rec_stand) -> dict:
    """The concealed-effect suite's scores (and the twin's speed on ``spec_stand``/``rec_stand``
    when given)."""
    key = "diagnose.suite"
    mm = diagnose_suite.mini_mill()
    outcomes = []
    loads = []
    for case in diagnose_suite.SUITE:
        o = diagnose_suite.run_case(case)
        outcomes.append(o)
        loads.append(os.getloadavg()[0])
        print(_case_line(o), flush=True)
    figures = {f"{key}.{k}": (round(v, 2) if isinstance(v, float) else v)
               for k, v in diagnose_suite.score(outcomes).items()}
    figures[f"{key}.load_average_1min_range"] = f"{min(loads):.1f}-{max(loads):.1f}"
    for case in (diagnose_suite.SUITE[0], diagnose_suite.SUITE[22]):
        o = diagnose_suite.run_case(case, calibrate=True)
        figures[f"{key}.calibrate_first.{o['case']}.answer"] = o["answer"]
        figures[f"{key}.calibrate_first.{o['case']}.calibration_wall_s"] = round(o["calibration_wall_s"], 2)
        figures[f"{key}.calibrate_first.{o['case']}.diagnosis_wall_s"] = round(o["wall_s"], 2)
    rec_mm, _ = diagnose_suite.concealed_recording(mm, (), hours=48.0, step_s=300.0, seed=1)
    figures[f"{key}.twin_simulated_h_per_s.mini_mill_300s"] = round(twin_hours_per_s(mm, rec_mm), 0)
    if spec_stand is not None:
        figures[f"{key}.twin_simulated_h_per_s.spindle_stand_15s"] = round(twin_hours_per_s(spec_stand, rec_stand), 0)
    for k, v in figures.items():
        print(f"{k}: {v}", flush=True)
    return figures


if __name__ == "__main__":
    run()
