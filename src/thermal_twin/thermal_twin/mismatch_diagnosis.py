"""The mismatch finder end to end: simulate, locate, diagnose, hypothesise, model, report.

:func:`diagnose` takes a twin (YAML path, preset name or mapping) and a
:class:`~thermal_comp_common.recording_csv.Recording` and returns a :class:`Diagnosis` holding the
JSON-ready report (keys as issue 9 lists them), the augmented machine description and the
series for the plots. The recording is split chronologically: the first
``1 - holdout_fraction`` is the training window (every fit), the rest is held out (only
scored). Pure numpy/scipy; the command line is :mod:`thermal_twin.diagnose_cli`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from thermal_twin import mismatch_locate as locate
from thermal_twin import mismatch_statistics as stats
from thermal_twin.machine_schema import Machine, load_machine
from thermal_twin.mismatch_effects import EFFECTS, candidates, classify_driver
from thermal_twin.mismatch_fit import BIC_THRESHOLD, FitProblem, Hypothesis, run_round
from thermal_twin.mismatch_report import DiagnosisSeries
from thermal_twin.mismatch_testing import PROCEDURE
from thermal_twin.mismatch_twin_eval import single_threaded_blas
from thermal_twin import mismatch_unnamed as unnamed_mod
from thermal_comp_common.recording_csv import Recording, column_kind, error_unit
from thermal_comp_common.metrics import rmse

CORRELATED_NOTE = ("Candidate effects whose fitted output changes are nearly collinear on this "
                   "recording cannot be told apart by any fit; they are listed under "
                   "indistinguishable_from, and choosing between them needs a recording with "
                   "other operating regimes (or a sensor at the suspected place).")


class DiagnosisError(ValueError):
    """Twin and recording cannot be compared; the message names the cause."""


@dataclass
class Diagnosis:
    report: dict
    augmented_spec: dict | None          # None when no vocabulary effect is adopted
    series: DiagnosisSeries
    hypotheses: list[Hypothesis]
    calibrated_spec: dict | None = None  # with calibrate=True: the calibrated twin (search base)


def _search(problem: FitProblem, base: dict, y_base: np.ndarray, drivers: dict, channels: list[str],
            effects: tuple[str, ...], max_effects: int, shortlist: int, min_improvement_pct: float,
            progress: bool) -> tuple[list[Hypothesis], list[Hypothesis], dict, np.ndarray, list[int]]:
    """Greedy rounds of screening, fitting and testing; returns (adopted, all hypotheses,
    final description, its outputs, candidates screened per round)."""
    adopted: list[Hypothesis] = []
    all_hyps: list[Hypothesis] = []
    tried: list[int] = []
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(desc="screening candidates", unit="cand", leave=False)
    for round_no in range(1, max_effects + 1):
        cands = candidates(base, drivers, channels, effects)
        tried.append(len(cands))
        hyps = run_round(problem, base, cands, y_base, shortlist=shortlist,
                         min_improvement_pct=min_improvement_pct, round_no=round_no,
                         progress=(bar.update if bar is not None else None))
        all_hyps += hyps
        best = hyps[0] if hyps else None
        if best is None or not best.supported(min_improvement_pct):
            break
        adopted.append(best)
        base = best.spec
        y_base = problem.outputs(base)
    if bar is not None:
        bar.close()
    return adopted, all_hyps, base, y_base, tried


def _unnamed(problem: FitProblem, rec: Recording, ccf_inputs: dict, channels: list[str], errors: set,
             y_start: np.ndarray, y_named: np.ndarray, named: bool, min_improvement_pct: float):
    """The out-of-vocabulary step: a sparse discrepancy of the residual of ``y_start``. It
    answers when nothing of the vocabulary was adopted, or when it leaves less than half the
    held-out weighted residual the adopted vocabulary leaves (the vocabulary then only
    imitated it). Returns (discrepancies, outputs with them added) or ([], None)."""
    nt = problem.n_train
    meas = problem._meas
    resid = {c: np.where(problem._valid[i], meas[i] - y_start[i], np.nan) for i, c in enumerate(channels)}
    lib = unnamed_mod.signal_library(rec.time_s, ccf_inputs, rec.sensors)
    found = unnamed_mod.find_unnamed(resid, lib, nt, errors, min_improvement_pct)
    if not found:
        return [], None
    y_u = y_start.copy()
    for d in found:
        y_u[channels.index(d.channel)] += d.prediction
    sse_u = float(np.sum(problem.weighted_residual(y_u, nt) ** 2))
    sse_n = float(np.sum(problem.weighted_residual(y_named, nt) ** 2))
    if named and not sse_u < 0.5 * sse_n:
        return [], None
    return found, y_u


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


def _answer(found_unnamed: list, adopted: list, cal_section: dict | None, min_improvement_pct: float) -> str:
    """unnamed, the first adopted effect, ``mis-calibrated`` (calibrate-first moved existing
    parameters, improved the held-out fit by at least ``min_improvement_pct`` and nothing is
    missing) or ``none``."""
    if found_unnamed:
        return "unnamed"
    if adopted:
        return adopted[0].candidate.effect
    if (cal_section and cal_section["used_as_base"] and cal_section["mis_calibrated"]
            and cal_section["holdout_improvement_pct"] >= min_improvement_pct):
        return "mis-calibrated"
    return "none"


def _unit(ch: str) -> str:
    return "degC" if column_kind(ch) == "sensor" else error_unit(ch)


def _clean_inputs(rec: Recording, machine: Machine) -> Recording:
    """Interpolate failed readings (NaN) of input columns; the twin needs every input.
    An input column without any value is dropped (with a warning); a twin input the
    recording cannot supply falls back to the twin's default, also with a warning."""
    cols = dict(rec.columns)
    warnings = list(rec.warnings)
    for name in rec.names("input"):
        v = np.asarray(cols[name], dtype=float)
        bad = ~np.isfinite(v)
        if bad.any():
            if bad.all():
                del cols[name]
                warnings.append(f"column '{name}': no valid value, not used")
                continue
            cols[name] = np.interp(rec.time_s, rec.time_s[~bad], v[~bad])
            warnings.append(f"column '{name}': {int(bad.sum())} missing values interpolated")
    for name, ispec in machine.inputs.items():
        if name not in cols and not (ispec.from_sensor and f"{ispec.from_sensor}_c" in cols):
            warnings.append(f"twin input '{name}' is not in the recording: its default "
                            f"{ispec.default:g} {ispec.unit} is used")
    return Recording(rec.time_s, cols, source=rec.source, warnings=warnings)


def shared_channels(machine: Machine, rec: Recording) -> list[str]:
    chans = [machine.sensors[s].column for s in machine.sensors if machine.sensors[s].column in rec.columns]
    chans += [e for e in machine.errors if e in rec.columns]
    return [c for c in chans if np.isfinite(np.asarray(rec.columns[c], dtype=float)).sum() >= 8]


def diagnose(*args, **kwargs) -> Diagnosis:
    """:func:`_diagnose` (its arguments) with BLAS on one thread (see ``single_threaded_blas``)."""
    with single_threaded_blas():
        return _diagnose(*args, **kwargs)


def _diagnose(twin: str | Mapping | Machine, recording: Recording, holdout_fraction: float = 1 / 3,
              max_effects: int = 2, min_improvement_pct: float = 5.0, start_hour: float = 0.0,
              effects: tuple[str, ...] = EFFECTS, shortlist: int = 10, max_lag_s: float = 6 * 3600.0,
              progress: bool = False, calibrate: bool = False, calibration_section: Mapping | None = None,
              calibration_nfev: int = 20, unnamed: bool = True) -> Diagnosis:
    """Diagnose ``twin`` against ``recording``; see the module docstring. ``calibrate``:
    fit the twin's existing parameters first (:mod:`thermal_twin.mismatch_calibrated`);
    ``unnamed``: try a sparse out-of-vocabulary discrepancy (:mod:`thermal_twin.mismatch_unnamed`).
    (Over 80 lines: one pass from the comparison to the report, each step delegated.)"""
    if not 0.05 <= holdout_fraction <= 0.8:
        raise DiagnosisError(f"holdout_fraction: {holdout_fraction!r} must be within [0.05, 0.8]")
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise DiagnosisError(f"effects: {unknown[0]!r} is not in the vocabulary {list(EFFECTS)}")
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    rec = _clean_inputs(recording, machine)
    if len(rec) < 30:
        raise DiagnosisError(f"recording {rec.source}: {len(rec)} rows, need at least 30")
    channels = shared_channels(machine, rec)
    if not channels:
        raise DiagnosisError(
            f"recording {rec.source}: no channel shared with twin '{machine.name}' (twin sensors "
            f"{[machine.sensors[s].column for s in machine.sensors]}, errors {list(machine.errors)}; "
            f"recording columns {list(rec.columns)})")
    # the description keeps its sensor model (noise, resolution): the evaluation is
    # noise-free by construction, and the plausibility checks need the resolution
    spec0 = machine.to_dict()
    n = len(rec)
    n_train = int(round(n * (1.0 - holdout_fraction)))
    t = rec.time_s
    dt = float(np.median(np.diff(t)))
    resolution = {machine.sensors[sid].column: machine.sensors[sid].resolution for sid in machine.sensors}
    problem = FitProblem(rec, channels, n_train, resolution=resolution)
    y_given = problem.outputs(spec0)
    cal_section = None
    base0 = spec0
    if calibrate:
        from thermal_twin.mismatch_calibrated import calibrated_base
        base0, cal_section = calibrated_base(machine, problem, holdout_fraction, calibration_section,
                                             calibration_nfev)
    y0 = problem.outputs(base0) if calibrate else y_given
    meas = {c: np.asarray(rec.columns[c], dtype=float) for c in channels}
    units = {c: _unit(c) for c in channels}
    resid0 = {c: meas[c] - y0[i] for i, c in enumerate(channels)}

    # diagnose the residuals -------------------------------------------------------------
    ccf_inputs = dict(rec.inputs)
    for name, ispec in machine.inputs.items():   # e.g. the ambient the twin takes from a sensor
        col = f"{ispec.from_sensor}_c" if ispec.from_sensor else None
        if name not in ccf_inputs and col in rec.columns:
            ccf_inputs[name] = rec.columns[col]
    unknown_sensors = {c: v for c, v in rec.sensors.items() if c not in channels}
    drivers_all = stats.derived_drivers(t, ccf_inputs, rec.sensors)
    drivers_all.update({c: stats.fill_gaps(v) for c, v in unknown_sensors.items()
                        if np.isfinite(v).any()})
    max_lag = int(max_lag_s / dt)
    ccf: dict[str, list] = {}
    chan_report: dict[str, dict] = {}
    for c in channels:
        r = resid0[c]
        own = {c, f"d({c})/dt"}
        cc = [stats.cross_correlation(r, u, max_lag, name) for name, u in drivers_all.items()
              if name not in own and np.nanstd(u) > 0]
        cc.sort(key=lambda x: -abs(x.peak_value) / max(x.band, 1e-12))
        ccf[c] = [x for x in cc if x.significant][:5]
        chan_report[c] = {
            "unit": units[c],
            "ljung_box": stats.ljung_box(r),
            "drift": stats.drift(t, r),
            "spectral_peaks": stats.spectral_peaks(r, dt),
            "cross_correlation": [x.as_dict(dt) for x in ccf[c]],
        }

    regimes = locate.operating_regimes(t, rec.inputs, start_hour)
    windows = locate.locate_windows(t, resid0, regimes, units)
    reg_eff = locate.regime_effects(resid0, regimes, units)

    # hypothesise and model -----------------------------------------------------------------
    drivers = {name: classify_driver(name, v) for name, v in rec.inputs.items()}
    adopted, all_hyps, base, y_base, tried = _search(problem, base0, y0, drivers, channels, effects,
                                                     max_effects, shortlist, min_improvement_pct, progress)
    if calibrate and adopted:
        from thermal_twin.mismatch_calibrated import joint_adoption_test
        test = joint_adoption_test(machine, problem, holdout_fraction, adopted, base0, cal_section,
                                   calibration_section, min_improvement_pct)
        joint_spec = test.pop("spec")
        cal_section["adoption_test"] = test
        if test["passed"]:
            base, y_base = joint_spec, problem.outputs(joint_spec)
        else:
            adopted, base, y_base = [], base0, y0
    found_unnamed = []
    if unnamed:
        found_unnamed, y_u = _unnamed(problem, rec, ccf_inputs, channels, set(machine.errors), y0, y_base,
                                      bool(adopted), min_improvement_pct)
        if found_unnamed and calibrate:
            from thermal_twin.mismatch_calibrated import unnamed_beats_free_calibration
            test = unnamed_beats_free_calibration(machine, problem, holdout_fraction, y_u, cal_section,
                                                  calibration_section, min_improvement_pct)
            cal_section["unnamed_test"] = test
            if not test["passed"]:
                found_unnamed = []
        if found_unnamed:
            adopted, base, y_base = [], base0, y_u
    if cal_section is not None:
        cal_section.pop("_estimates", None)
    y1 = y_base
    for c in channels:
        i = channels.index(c)
        chan_report[c].update({
            "rmse_before": rmse(meas[c], y_given[i]), "rmse_after": rmse(meas[c], y1[i]),
            "holdout_rmse_calibrated": rmse(meas[c][n_train:], y0[i][n_train:]),
            "holdout_rmse_before": rmse(meas[c][n_train:], y_given[i][n_train:]),
            "holdout_rmse_after": rmse(meas[c][n_train:], y1[i][n_train:]),
            "train_rmse_before": rmse(meas[c][:n_train], y_given[i][:n_train]),
            "train_rmse_after": rmse(meas[c][:n_train], y1[i][:n_train]),
            "noise_sigma": problem.sigma[c],
        })
        chan_report[c] = {k: chan_report[c][k] for k in
                          ("unit", "rmse_before", "rmse_after", "holdout_rmse_before", "holdout_rmse_calibrated",
                           "holdout_rmse_after",
                           "train_rmse_before", "train_rmse_after", "noise_sigma", "ljung_box", "drift",
                           "spectral_peaks", "cross_correlation")}

    notes = [f"Day/night regimes assume time_s = 0 at {start_hour:g} h clock time (--start-hour)."]
    if any(h.indistinguishable_from for h in all_hyps if h.plausible):
        notes.append(CORRELATED_NOTE)
    notes += rec.warnings
    ranked = sorted(all_hyps, key=lambda h: (h.round, h.rank_key(min_improvement_pct)))
    report = {
        "twin": machine.source_path or machine.name,
        "recording": rec.source,
        "split": {"train_end_s": float(t[n_train - 1]), "holdout_start_s": float(t[n_train]),
                  "end_s": float(t[-1]), "holdout_fraction": holdout_fraction},
        "channels": chan_report,
        "windows": windows,
        "regime_effects": reg_eff[:20],
        "hypotheses": [h.as_dict() for h in ranked],
        "selected": [h.as_dict() for h in adopted] if adopted else "none",
        "unnamed": [d.as_dict(units[d.channel]) for d in found_unnamed],
        "answer": _answer(found_unnamed, adopted, cal_section, min_improvement_pct),
        "calibration": cal_section,
        "augmented_twin": None,
        "criteria": {"min_holdout_improvement_pct": min_improvement_pct, "max_delta_bic": BIC_THRESHOLD,
                     "max_effects": max_effects, "multiple_testing": PROCEDURE,
                     "candidates_screened_per_round": tried},
        "simulations": problem.n_evals,
        "notes": notes,
    }
    series = DiagnosisSeries(
        time_s=t, measured=meas, before={c: y_given[i] for i, c in enumerate(channels)},
        after={c: y1[i] for i, c in enumerate(channels)}, holdout_start_s=float(t[n_train]),
        ccf=ccf, dt_s=dt)
    return Diagnosis(report, copy.deepcopy(base) if adopted else None, series, all_hyps,
                     copy.deepcopy(base0) if calibrate else None)
