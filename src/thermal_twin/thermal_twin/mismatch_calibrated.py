"""Calibrate first, then search: the "mis-calibrated" half of a diagnosis.

``diagnose(..., calibrate=True)`` fits the twin's existing parameters on the training
window (:func:`thermal_twin.calibration.calibrate`) before any effect is tried, so that an
effect is adopted only if it beats, on held-out data, what re-calibrating the existing
parameters achieves (the effect is fitted and tested against the calibrated twin). The
calibrated twin is kept as the search's base only if it does not fit the held-out window
worse than the twin as given; the report lists which parameters moved, by how much, with
their 95 % intervals.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from thermal_twin.calibration import CalibrationResult, calibrate
from thermal_twin.machine_schema import Machine
from thermal_twin.mismatch_fit import FitProblem


def moved(res: CalibrationResult) -> list[dict]:
    """Parameters whose 95 % interval excludes their start value, largest change first."""
    out = []
    for e in res.estimates:
        lo, hi = e.ci95
        if any(f.startswith("not identified") for f in e.flags) or lo <= e.param.value0 <= hi:
            continue
        d = e.as_dict()
        out.append({k: d[k] for k in ("name", "kind", "unit", "start", "value", "change_pct", "ci95", "flags")})
    out.sort(key=lambda d: -abs(d["change_pct"] or 0.0))
    return out


def calibrated_base(machine: Machine, problem: FitProblem, holdout_fraction: float,
                    section: Mapping | None = None, max_nfev: int = 20) -> tuple[dict, dict]:
    """(base description for the search, report section ``calibration``)."""
    spec0 = machine.to_dict()
    res = calibrate(machine, problem.recording, holdout_fraction=holdout_fraction, section=section,
                    max_nfev=max_nfev)
    nt = problem.n_train
    sse = {}
    for label, spec in (("given", spec0), ("calibrated", res.spec)):
        r = problem.weighted_residual(problem.outputs(spec), nt)
        sse[label] = float(np.sum(r ** 2))
    used = sse["calibrated"] <= sse["given"]
    unid = [e.param.name for e in res.estimates if any(f.startswith("not identified") for f in e.flags)]
    section_out = {
        "used_as_base": used,
        "free_parameters": len(res.estimates),
        "not_identified": len(unid),
        "correlated_pairs": len(res.correlated),
        "mis_calibrated": moved(res),
        "holdout_improvement_pct": 100.0 * (1.0 - sse["calibrated"] / max(sse["given"], 1e-300)),
        "cost_before": res.cost_before, "cost_after": res.cost_after,
        "twin_evaluations": res.n_evals, "wall_s": res.wall_s,
        "simulated_h_per_s": res.simulated_h / max(res.wall_s, 1e-9), "status": res.status,
        "note": ("effects below were fitted and tested against the calibrated twin: an effect is "
                 "adopted only if it beats, on held-out data, what re-calibrating the existing "
                 "parameters achieves" if used else
                 "the calibrated twin fits the held-out window worse than the twin as given "
                 "(over-fitted on the training window); the search starts from the twin as given"),
    }
    return (res.spec if used else spec0), section_out
