"""Calibrate first, then search: the "mis-calibrated" half of a diagnosis.

``diagnose(..., calibrate=True)`` fits the twin's existing parameters on the training
window (:func:`thermal_twin.calibrate.fit.calibrate`) before any effect is tried, so that an
effect is adopted only if it beats, on held-out data, what re-calibrating the existing
parameters achieves (the effect is fitted and tested against the calibrated twin). The
calibrated twin is kept as the search's base only if it does not fit the held-out window
worse than the twin as given; the report lists which parameters moved, by how much, with
their 95 % intervals. :func:`joint_adoption_test` then re-calibrates the twin *with* the
adopted effects (existing parameters and the effects' own, jointly, same priors) and keeps
the effects only if that beats the calibration alone on held-out data;
:func:`unnamed_beats_free_calibration` keeps an ``unnamed`` discrepancy only if it beats
the existing parameters fitted without the prior's pull (all a re-calibration within the
tolerances can do): the prior's shrinkage leaves a structured residual that a sparse term
would otherwise pick up on a twin that is only mis-calibrated.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_twin.calibrate.fit import CalibrationResult, calibrate
from thermal_twin.machine.schema import Machine
from thermal_twin.diagnose.fit import FitProblem, worse_channels


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


#: a parameter within this share of its tolerance range from a bound was pushed to it
BOUND_SHARE = 0.02
#: a channel whose calibrated training residual (mean removed) stays above this many noise
#: sigmas RMS, and above half the twin-as-given's, is structured: the calibration did not explain it
STRUCTURED_RMS = 2.0


def at_bound(res: CalibrationResult) -> list[dict]:
    """Parameters the calibration pushed to the builder's tolerance bound, largest change
    first: evidence of missing or changed physics, not an answer."""
    out = []
    for e in res.estimates:
        p = e.param
        span = p.hi - p.lo
        if span > 0 and min(e.value - p.lo, p.hi - e.value) <= BOUND_SHARE * span:
            d = e.as_dict()
            out.append({k: d[k] for k in ("name", "kind", "unit", "start", "value", "change_pct", "bounds")})
    out.sort(key=lambda d: -abs(d["change_pct"] or 0.0))
    return out


def _train_rms(problem: FitProblem, y: np.ndarray) -> np.ndarray:
    """Per channel: RMS of the weighted training residual of ``y`` with its mean removed."""
    nt = problem.n_train
    r = problem.weighted_residual(y, 0, nt)
    v = problem._valid[:, :nt]
    out = np.zeros(len(r))
    for i in range(len(r)):
        if v[i].sum() >= 2:
            x = r[i][v[i]]
            out[i] = float(np.sqrt(np.mean((x - x.mean()) ** 2)))
    return out


def structured_channels(problem: FitProblem, y_given: np.ndarray, y_cal: np.ndarray) -> list[dict]:
    """Channels the calibration did not explain: its training residual (mean removed) stays
    above :data:`STRUCTURED_RMS` noise sigmas RMS and above half the twin-as-given's, largest
    first (the training window only: the held-out window stays for scoring)."""
    given, cal = _train_rms(problem, y_given), _train_rms(problem, y_cal)
    out = [{"channel": c, "train_rms_over_noise": float(cal[i]), "given_train_rms_over_noise": float(given[i])}
           for i, c in enumerate(problem.channels) if cal[i] > STRUCTURED_RMS and cal[i] > 0.5 * given[i]]
    return sorted(out, key=lambda d: -d["train_rms_over_noise"])


def calibrated_base(machine: Machine, problem: FitProblem, holdout_fraction: float,
                    section: Mapping | None = None, max_nfev: int = 20,
                    engine: EngineSpec | None = None) -> tuple[dict, dict]:
    """(base description for the search, report section ``calibration``); ``engine``: where
    the calibration's Jacobian columns run (the same answer on every engine)."""
    spec0 = machine.to_dict()
    res = calibrate(machine, problem.recording, holdout_fraction=holdout_fraction, section=section,
                    max_nfev=max_nfev, engine=engine)
    nt = problem.n_train
    sse = {}
    for label, spec in (("given", spec0), ("calibrated", res.spec)):
        r = problem.weighted_residual(problem.outputs(spec), nt)
        sse[label] = float(np.sum(r ** 2))
    bound = at_bound(res)
    y_given, y_cal = problem.outputs(spec0), problem.outputs(res.spec)
    structured = structured_channels(problem, y_given, y_cal)
    # a parameter at its bound means the calibration stood in for physics it cannot reach, a
    # residual that stays structured that it did not explain it: either way the search starts
    # from the twin as given, where that physics is still visible (the joint test still
    # compares with the calibration alone)
    worse = worse_channels(problem, y_given, y_cal)
    used = sse["calibrated"] <= sse["given"] and not bound and not structured and not worse
    unid = [e.param.name for e in res.estimates if any(f.startswith("not identified") for f in e.flags)]
    section_out = {
        "used_as_base": used,
        "free_parameters": len(res.estimates),
        "not_identified": len(unid),
        "correlated_pairs": len(res.correlated),
        "mis_calibrated": moved(res),
        "at_bound": bound,
        "worse_channels": worse,
        "residual_structured": structured,
        "holdout_improvement_pct": 100.0 * (1.0 - sse["calibrated"] / max(sse["given"], 1e-300)),
        "cost_before": res.cost_before, "cost_after": res.cost_after,
        "twin_evaluations": res.n_evals, "wall_s": res.wall_s,
        "simulated_h_per_s": res.simulated_h / max(res.wall_s, 1e-9), "status": res.status,
        "note": ("effects below were fitted and tested against the calibrated twin: an effect is "
                 "adopted only if it beats, on held-out data, what re-calibrating the existing "
                 "parameters achieves" if used else
                 f"{len(bound)} parameter(s) pushed to the builder's tolerance bound, evidence of missing "
                 "or changed physics; the search starts from the twin as given and an effect is kept only "
                 "if it beats the calibration alone" if bound else
                 f"the calibrated residual stays structured on {len(structured)} channel(s); the search "
                 "starts from the twin as given and an effect is kept only if it beats the calibration "
                 "alone" if structured else
                 "the calibrated twin fits the held-out window worse than the twin as given "
                 "(over-fitted on the training window); the search starts from the twin as given"),
    }
    section_out["_estimates"] = res.estimates      # for the joint test's start; dropped from the report
    section_out["_spec"] = res.spec                # "calibration alone" of the joint test; dropped too
    return (res.spec if used else spec0), section_out


def joint_adoption_test(machine: Machine, problem: FitProblem, holdout_fraction: float,
                        adopted: list, base_spec: dict, calibrated: dict, section: Mapping | None,
                        min_improvement_pct: float, max_nfev: int = 20, engine: EngineSpec | None = None) -> dict:
    """"Calibration + effects" against "calibration alone" on the held-out window: the
    twin as given plus the adopted effects (each at its fitted values) is calibrated
    jointly, starting from the calibrated values, with the same tolerances and priors
    (the effects' new parameters get their kind's tolerance around the fitted value).
    Returns the report's ``adoption_test`` section; ``passed`` decides the adoption."""
    spec = machine.to_dict()
    for h in adopted:
        spec = h.candidate.apply(spec, h.values)
    start = {e.param.name: e.value for e in calibrated.get("_estimates", [])}
    res = calibrate(spec, problem.recording, holdout_fraction=holdout_fraction, section=section,
                    max_nfev=max_nfev, start=start, engine=engine)
    nt = problem.n_train
    # calibration alone: the better of the search's base and the calibrated twin (the search
    # may start from the twin as given when the calibration pushed a parameter to its bound)
    sse_alone = min(float(np.sum(problem.weighted_residual(problem.outputs(s), nt) ** 2))
                    for s in (base_spec, calibrated.get("_spec", base_spec)))
    sse_joint = float(np.sum(problem.weighted_residual(problem.outputs(res.spec), nt) ** 2))
    gain = 100.0 * (1.0 - sse_joint / max(sse_alone, 1e-300))
    return {"effects": [f"{h.candidate.effect}:{h.candidate.target}:{h.candidate.driver or '-'}"
                        for h in adopted],
            "holdout_sse_calibration_alone": sse_alone, "holdout_sse_calibration_with_effects": sse_joint,
            "holdout_improvement_pct": gain, "passed": gain >= min_improvement_pct,
            "wall_s": res.wall_s, "twin_evaluations": res.n_evals, "spec": res.spec}


def holdout_sse_with_offsets(problem: FitProblem, y: np.ndarray) -> float:
    """Held-out weighted SSE of ``y`` after each channel's training-window mean residual is
    removed: the unnamed discrepancy is fitted with an offset per channel, so what it is
    compared with after calibrating gets one too (an offset alone is a bias: vocabulary)."""
    nt = problem.n_train
    r = problem.weighted_residual(y)
    v = problem._valid
    mean = np.array([r[i, :nt][v[i, :nt]].mean() if v[i, :nt].any() else 0.0 for i in range(len(r))])
    rh = np.where(v[:, nt:], r[:, nt:] - mean[:, None], 0.0)
    return float(np.sum(rh ** 2))


def unnamed_beats_free_calibration(machine: Machine, problem: FitProblem, holdout_fraction: float,
                                   y_unnamed: np.ndarray, calibrated: dict, section: Mapping | None,
                                   min_improvement_pct: float, max_nfev: int = 10,
                                   engine: EngineSpec | None = None) -> dict:
    """The report's ``unnamed_test``: held-out weighted SSE of the calibrated twin with the
    unnamed discrepancy against the twin calibrated without the prior (within the same
    tolerances, from the calibrated values), both with each channel's training offset
    removed; ``passed`` decides."""
    start = {e.param.name: e.value for e in calibrated.get("_estimates", [])}
    res = calibrate(machine, problem.recording, holdout_fraction=holdout_fraction, section=section,
                    max_nfev=max_nfev, prior=False, start=start, engine=engine)
    sse_free = holdout_sse_with_offsets(problem, problem.outputs(res.spec))
    sse_u = holdout_sse_with_offsets(problem, y_unnamed)
    gain = 100.0 * (1.0 - sse_u / max(sse_free, 1e-300))
    return {"holdout_sse_free_calibration": sse_free, "holdout_sse_with_unnamed": sse_u,
            "holdout_improvement_pct": gain, "passed": gain >= min_improvement_pct,
            "wall_s": res.wall_s, "twin_evaluations": res.n_evals}
