"""The mismatch finder end to end: simulate, locate, diagnose, hypothesise, model, report.

:func:`diagnose` takes a twin (YAML path, preset name or mapping) and a
:class:`~thermal_comp_common.recording_csv.Recording` and returns a :class:`Diagnosis` holding the
JSON-ready report (its keys: docs/diagnose.md), the augmented machine description and the
series for the plots. The recording is split chronologically: the first
``1 - holdout_fraction`` is the training window (every fit), the rest is held out (only
scored). Pure numpy/scipy; the command line is :mod:`thermal_twin.diagnose.cli`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from thermal_twin.diagnose import clock, residuals
from thermal_twin.diagnose import unnamed as unnamed_mod
from thermal_twin.diagnose.calibrated import (calibrated_base, joint_adoption_test,
                                               unnamed_beats_free_calibration)
from thermal_twin.machine.schema import Machine, load_machine
from thermal_twin.diagnose.effects import EFFECTS, classify_driver
from thermal_twin.diagnose.fit import BIC_THRESHOLD, FitProblem, Hypothesis, effective_samples, worse_channels
from thermal_twin.diagnose.statistics import recorded_resolution
from thermal_twin.diagnose.report import DiagnosisSeries
from thermal_twin.diagnose.search_round import RoundInputs, exchange, prune, run_round
from thermal_twin.diagnose.twin_eval import gap_uncertain_readings
from thermal_twin.sim.inputs_timeline import timeline_from_recording
from thermal_twin.diagnose.significance import ALPHA, PROCEDURE, holdout_p_value
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.engine_options import held_engine
from thermal_comp_common.bags.recording import MIN_CHANNEL_VALUES, MIN_RECORDING_ROWS
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording, column_kind, error_unit
from thermal_comp_common.runtime.task_engine import EngineSpec

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
            progress: bool, engine: EngineSpec | None = None, notes: list | None = None
            ) -> tuple[list[Hypothesis], list[Hypothesis], dict, np.ndarray, list[int]]:
    """Greedy rounds of screening, fitting and testing (each round's candidates on the task
    engine); returns (adopted, all hypotheses, final description, its outputs, candidates
    screened per round)."""
    adopted: list[Hypothesis] = []
    all_hyps: list[Hypothesis] = []
    rounds: list[list[Hypothesis]] = []
    tried: list[int] = []
    spec_first, y_first = base, y_base
    bar = None
    if progress:
        from tqdm import tqdm  # optional: only for the progress bar
        bar = tqdm(desc="screening candidates", unit="cand", leave=False)
    for round_no in range(1, max_effects + 1):
        inputs = RoundInputs(problem, base, y_base, drivers, channels, effects)
        hyps, n_cands = run_round(inputs, shortlist=shortlist, min_improvement_pct=min_improvement_pct,
                                  round_no=round_no, progress=(bar.update if bar is not None else None),
                                  engine=engine)
        tried.append(n_cands)
        all_hyps += hyps
        best = hyps[0] if hyps else None
        if best is None or not best.supported(min_improvement_pct):
            break
        adopted.append(best)
        rounds.append(hyps)
        base = best.spec
        y_base = problem.outputs(base)
    if bar is not None:
        bar.close()
    if adopted:
        # rivals of each round's choice tried with the others refitted (search_round.exchange),
        # then refitted together, each paying for itself, no channel worse (search_round.prune)
        notes = notes if notes is not None else []
        adopted, swap = exchange(problem, spec_first, y_first, rounds, adopted, min_improvement_pct)
        if swap:
            notes.append(f"exchanged {swap['greedy']} for {swap['exchanged']}: held-out weighted sum of squares "
                         f"{swap['holdout_sse_greedy']:.4g} -> {swap['holdout_sse_exchanged']:.4g} when refitted together")
        adopted, dropped = prune(problem, spec_first, y_first, adopted, min_improvement_pct)
        notes.extend(f"{d['effect']} dropped: {d['reason']}" for d in dropped)
        base = adopted[-1].spec if adopted else spec_first
        y_base = problem.outputs(base) if adopted else y_first
    return adopted, all_hyps, base, y_base, tried


#: a discrepancy left after the adopted words that explains at least this share of their
#: held-out residual on its channel shows the words leave a structured residual there
LEFTOVER_PCT = 50.0


def _discrepancies(problem: FitProblem, lib: list, channels: list[str], errors: set, y: np.ndarray,
                   min_improvement_pct: float, engine: EngineSpec | None, only: set | None = None) -> list:
    resid = {c: np.where(problem._valid[i], problem._meas[i] - y[i], np.nan) for i, c in enumerate(channels)
             if only is None or c in only}
    return unnamed_mod.find_unnamed(resid, lib, problem.n_train, errors, min_improvement_pct, engine)


def _acted(problem: FitProblem, y_start: np.ndarray, y_named: np.ndarray) -> set:
    """The channels the adopted words change: held-out RMS of the change above half a noise sigma."""
    change = problem.weighted(y_named - y_start)[:, problem.n_train:]
    return {c for i, c in enumerate(problem.channels) if np.sqrt(np.mean(change[i] ** 2)) > 0.5}


def _with(y: np.ndarray, found: list, channels: list[str]) -> np.ndarray:
    """Outputs ``y`` with the discrepancies' formulas added on their channels."""
    y = y.copy()
    for d in found:
        y[channels.index(d.channel)] += d.prediction
    return y


def _words_add(problem: FitProblem, sse_u: float, y_named: np.ndarray, left: list, acted: np.ndarray,
               word_params: int) -> bool:
    """Whether the adopted words explain held-out structure the discrepancy cannot (an
    encompassing test): the words with the discrepancy of the residual they leave (``left``)
    against the discrepancy of the twin's own residual alone (``sse_u``), on the words'
    channels, by the held-out F test with ``word_params`` parameters and the effective
    samples of the combined residual. On a real machine every fit leaves a structured residual
    (the twin's own misfit), which a discrepancy of the other recorded temperatures explains
    before and after the word alike; the word is then still needed beside it. Words that only
    imitated out-of-vocabulary physics add nothing the discrepancy does not already explain."""
    r = problem.weighted_residual(_with(y_named, left, problem.channels), problem.n_train)[acted]
    sse_wu = float(np.sum(r ** 2))
    return holdout_p_value(sse_u, sse_wu, word_params, effective_samples(r)) < ALPHA


def _unnamed(problem: FitProblem, rec: Recording, ccf_inputs: dict, channels: list[str], errors: set,
             y_start: np.ndarray, y_named: np.ndarray, named: str | None, min_improvement_pct: float,
             engine: EngineSpec | None = None, word_params: int = 1):
    """The out-of-vocabulary step: a sparse discrepancy of the residual of ``y_start``. It
    answers when nothing of the vocabulary was adopted (``named`` None), or when, on the
    channels the adopted words act on, it leaves less than half the held-out weighted residual
    they leave, or less while they leave a structured residual there (a discrepancy of their
    residual explaining :data:`LEFTOVER_PCT` of it), and the words (``word_params`` fitted
    parameters) add nothing significant beside it (:func:`_words_add`): the words only
    imitated physics outside the vocabulary; ``named`` is said as the nearest.
    Returns (discrepancies, outputs with them added) or ([], None)."""
    nt = problem.n_train
    lib = unnamed_mod.signal_library(rec.time_s, ccf_inputs, rec.sensors)
    found = _discrepancies(problem, lib, channels, errors, y_start, min_improvement_pct, engine)
    # the formula as printed must not leave its channel worse
    worse = set(worse_channels(problem, y_start, _with(y_start, found, channels))) if found else set()
    found = [d for d in found if d.channel not in worse]
    if not found:
        return [], None
    y_u = _with(y_start, found, channels)
    if named:
        # judged on the channels the words act on: terms elsewhere (a slow random walk of another
        # sensor) say nothing about whether the words only imitated out-of-vocabulary physics
        acted_set = _acted(problem, y_start, y_named)
        acted = np.array([c in acted_set for c in channels])
        if not any(acted[channels.index(d.channel)] for d in found):
            return [], None
        sse_u = float(np.sum(problem.weighted_residual(y_u, nt)[acted] ** 2))
        sse_n = float(np.sum(problem.weighted_residual(y_named, nt)[acted] ** 2))
        if not sse_u < sse_n:
            return [], None
        left = _discrepancies(problem, lib, channels, errors, y_named, min_improvement_pct, engine, acted_set)
        if not (sse_u < 0.5 * sse_n or any(d.holdout_improvement_pct >= LEFTOVER_PCT for d in left)):
            return [], None
        if _words_add(problem, sse_u, y_named, left, acted, word_params):
            return [], None
        for d in found:
            d.nearest = named
    return found, y_u


def _answer(found_unnamed: list, adopted: list, cal_section: dict | None, min_improvement_pct: float) -> str:
    """unnamed, the first adopted effect, ``beyond-tolerance`` (calibrate-first pushed a
    parameter to its tolerance bound and nothing was named), ``mis-calibrated`` (calibrate-first
    moved existing parameters, improved the held-out fit by at least ``min_improvement_pct`` and
    nothing is missing) or ``none``. A calibrated residual that stays structured but that neither
    the vocabulary nor an input-driven unnamed term predicts is no evidence of missing physics
    (coloured noise looks the same): it is reported per channel, and the answer is ``none``."""
    if found_unnamed:
        return "unnamed"
    if adopted:
        return adopted[0].candidate.effect
    if cal_section and cal_section.get("at_bound"):
        return "beyond-tolerance"
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
    return [c for c in chans if np.isfinite(np.asarray(rec.columns[c], dtype=float)).sum() >= MIN_CHANNEL_VALUES]


@dataclass
class _Comparison:
    """The twin beside the recording: what every step of a diagnosis reads."""

    machine: Machine
    rec: Recording
    channels: list[str]
    problem: FitProblem
    holdout_fraction: float
    y_given: np.ndarray          # outputs of the twin as given
    base0: dict                  # the search's base: the twin as given, or calibrated
    y0: np.ndarray               # outputs of base0
    cal_section: dict | None
    clock_offset: "clock.ClockOffset | None" = None

    @property
    def n_train(self) -> int:
        return self.problem.n_train

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.rec.time_s)))

    def measured(self) -> dict[str, np.ndarray]:
        return {c: np.asarray(self.rec.columns[c], dtype=float) for c in self.channels}

    def units(self) -> dict[str, str]:
        return {c: _unit(c) for c in self.channels}


def diagnose(*args, engine: EngineSpec | None = None, **kwargs) -> Diagnosis:
    """:func:`_diagnose` (its arguments) with BLAS on one thread (see ``single_thread_blas``).
    ``engine``: where the independent tasks (channel analysis, candidate screening and fits,
    out-of-vocabulary fits per channel) run; default serial in this process. The answer is
    the same on every engine (results are put back in the tasks' order)."""
    with single_thread_blas(), held_engine(engine) as held:
        return _diagnose(*args, engine=held, **kwargs)


def _diagnose(twin: str | Mapping | Machine, recording: Recording, holdout_fraction: float = 1 / 3,
              max_effects: int = 2, min_improvement_pct: float = 5.0, start_hour: float = 0.0,
              effects: tuple[str, ...] = EFFECTS, shortlist: int = 10, max_lag_s: float = 6 * 3600.0,
              progress: bool = False, calibrate: bool = False, calibration_section: Mapping | None = None,
              calibration_nfev: int = 20, unnamed: bool = True, clock_offset: bool = True,
              engine: EngineSpec | None = None) -> Diagnosis:
    """Diagnose ``twin`` against ``recording``; see the module docstring. ``calibrate``:
    fit the twin's existing parameters first (:mod:`thermal_twin.diagnose.calibrated`);
    ``unnamed``: try a sparse out-of-vocabulary discrepancy (:mod:`thermal_twin.diagnose.unnamed`);
    ``clock_offset``: look for a common time shift of the measured channels first.
    Three steps: residual analysis, search rounds, report assembly."""
    if not 0.05 <= holdout_fraction <= 0.8:
        raise DiagnosisError(f"holdout_fraction: {holdout_fraction!r} must be within [0.05, 0.8]")
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise DiagnosisError(f"effects: {unknown[0]!r} is not in the vocabulary {list(EFFECTS)}")
    cmp = _compare(twin, recording, holdout_fraction, calibrate, calibration_section, calibration_nfev, engine,
                   clock_offset)
    ccf_inputs = residuals.driver_inputs(cmp.rec, cmp.machine)
    analysis = residuals.analyse(cmp.rec, cmp.channels, cmp.measured(), cmp.y0, cmp.units(), ccf_inputs,
                                 max_lag_s, start_hour, engine)
    found = _find_missing(cmp, ccf_inputs, effects, max_effects, shortlist, min_improvement_pct, progress,
                          calibrate, calibration_section, unnamed, engine)
    report = _report(cmp, analysis, found, start_hour, min_improvement_pct, max_effects)
    series = DiagnosisSeries(
        time_s=cmp.rec.time_s, measured=cmp.measured(),
        before={c: cmp.y_given[i] for i, c in enumerate(cmp.channels)},
        after={c: found.y_base[i] for i, c in enumerate(cmp.channels)},
        holdout_start_s=float(cmp.rec.time_s[cmp.n_train]), ccf=analysis.ccf, dt_s=cmp.dt)
    return Diagnosis(report, copy.deepcopy(found.base) if found.adopted else None, series, found.all_hyps,
                     copy.deepcopy(cmp.base0) if calibrate else None)


def _exclude_gap_rows(problem: FitProblem, machine: Machine, rec: Recording) -> None:
    """The readings :func:`twin_eval.gap_uncertain_readings` names (after a gap hiding an input
    change whose unknown instant moves the twin by more than the noise) are left out of every
    fit and score: there no twin, whatever physics it has, can be compared with the reading."""
    mask = gap_uncertain_readings(machine, rec.time_s, timeline_from_recording(machine, rec).resolved(machine),
                                  problem.channels, problem.sigma)
    if mask is not None:
        problem.exclude(mask)


def _compare(twin, recording: Recording, holdout_fraction: float, calibrate: bool,
             calibration_section: Mapping | None, calibration_nfev: int,
             engine: EngineSpec | None = None, clock_offset: bool = True) -> _Comparison:
    """Check the inputs, simulate the twin as given, remove a clock offset of the measured
    channels (:mod:`thermal_twin.diagnose.clock`) and (with ``calibrate``) calibrate the twin."""
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    rec = _clean_inputs(recording, machine)
    if len(rec) < MIN_RECORDING_ROWS:
        raise DiagnosisError(f"recording {rec.source}: {len(rec)} rows, need at least {MIN_RECORDING_ROWS}")
    channels = shared_channels(machine, rec)
    if not channels:
        raise DiagnosisError(
            f"recording {rec.source}: no channel shared with twin '{machine.name}' (twin sensors "
            f"{[machine.sensors[s].column for s in machine.sensors]}, errors {list(machine.errors)}; "
            f"recording columns {list(rec.columns)})")
    # the description keeps its sensor model (noise, resolution): the evaluation is
    # noise-free by construction, and the plausibility checks need the resolution
    spec0 = machine.to_dict()
    n_train = int(round(len(rec) * (1.0 - holdout_fraction)))
    resolution = recorded_resolution({machine.sensors[sid].column: machine.sensors[sid].resolution
                                      for sid in machine.sensors}, rec.columns, channels)
    problem = FitProblem(rec, channels, n_train, resolution=resolution)
    y_given = problem.outputs(spec0)
    offset = None
    if clock_offset:
        offset = clock.estimate(rec.time_s, problem._meas, problem._valid, y_given, n_train)
        if offset.applied:
            # the noise of the re-sampled readings is smoothed: keep the weights of the raw ones
            rec = clock.realign(rec, offset.shift_s)
            problem = FitProblem(rec, channels, n_train, sigma=problem.sigma, resolution=resolution)
            y_given = problem.outputs(spec0)
    _exclude_gap_rows(problem, machine, rec)
    base0, y0, cal_section = spec0, y_given, None
    if calibrate:
        base0, cal_section = calibrated_base(machine, problem, holdout_fraction, calibration_section,
                                             calibration_nfev, engine)
        y0 = problem.outputs(base0)
    return _Comparison(machine, rec, channels, problem, holdout_fraction, y_given, base0, y0, cal_section, offset)


@dataclass
class _Found:
    """What the search step found (vocabulary effects, or an unnamed discrepancy)."""

    adopted: list[Hypothesis]
    all_hyps: list[Hypothesis]
    base: dict                    # final description
    y_base: np.ndarray            # its outputs (with an unnamed discrepancy added)
    tried: list[int]              # candidates screened per round
    unnamed: list
    notes: list                   # what the search dropped and why


def _find_missing(cmp: _Comparison, ccf_inputs: dict, effects, max_effects: int, shortlist: int,
                  min_improvement_pct: float, progress: bool, calibrate: bool,
                  calibration_section: Mapping | None, unnamed: bool, engine: EngineSpec | None) -> _Found:
    """Search rounds, the joint adoption test (calibrate-first), the out-of-vocabulary step."""
    rec, problem, cal_section = cmp.rec, cmp.problem, cmp.cal_section
    drivers = {name: classify_driver(name, v) for name, v in rec.inputs.items()}
    notes: list[str] = []
    adopted, all_hyps, base, y_base, tried = _search(problem, cmp.base0, cmp.y0, drivers, cmp.channels, effects,
                                                     max_effects, shortlist, min_improvement_pct, progress,
                                                     engine, notes)
    if calibrate and adopted:
        test = joint_adoption_test(cmp.machine, problem, cmp.holdout_fraction, adopted, cmp.base0, cal_section,
                                   calibration_section, min_improvement_pct, engine=engine)
        joint_spec = test.pop("spec")
        cal_section["adoption_test"] = test
        y_joint = problem.outputs(joint_spec)
        # the kept twin must not leave any channel worse than the twin as given
        test["worse_channels"] = worse_channels(problem, cmp.y_given, y_joint)
        test["passed"] = bool(test["passed"] and not test["worse_channels"])
        if test["passed"]:
            base, y_base = joint_spec, y_joint
        else:
            adopted, base, y_base = [], cmp.base0, cmp.y0
    found_unnamed = []
    if unnamed:
        found_unnamed, y_u = _unnamed(problem, rec, ccf_inputs, cmp.channels, set(cmp.machine.errors), cmp.y0,
                                      y_base, adopted[0].candidate.effect if adopted else None,
                                      min_improvement_pct, engine, sum(len(h.values) for h in adopted) or 1)
        if found_unnamed and calibrate:
            test = unnamed_beats_free_calibration(cmp.machine, problem, cmp.holdout_fraction, y_u, cal_section,
                                                  calibration_section, min_improvement_pct, engine=engine)
            cal_section["unnamed_test"] = test
            if not test["passed"]:
                found_unnamed = []
        if found_unnamed:
            adopted, base, y_base = [], cmp.base0, y_u
    if cal_section is not None:
        cal_section.pop("_estimates", None)
        cal_section.pop("_spec", None)
    return _Found(adopted, all_hyps, base, y_base, tried, found_unnamed, notes)


REPORT_CHANNEL_KEYS = ("unit", "rmse_before", "rmse_after", "holdout_rmse_before", "holdout_rmse_calibrated",
                       "holdout_rmse_after", "train_rmse_before", "train_rmse_after", "noise_sigma", "ljung_box",
                       "drift", "spectral_peaks", "cross_correlation")


def _channel_scores(cmp: _Comparison, analysis: "residuals.ResidualAnalysis", y1: np.ndarray) -> dict:
    """The report's ``channels``: fit scores before/after beside the residual statistics."""
    meas, k = cmp.measured(), cmp.n_train
    out = {}
    for i, c in enumerate(cmp.channels):
        m, yg, y0 = meas[c], cmp.y_given[i], cmp.y0[i]
        entry = dict(analysis.channels[c])
        entry.update({
            "rmse_before": rmse(m, yg), "rmse_after": rmse(m, y1[i]),
            "holdout_rmse_calibrated": rmse(m[k:], y0[k:]),
            "holdout_rmse_before": rmse(m[k:], yg[k:]), "holdout_rmse_after": rmse(m[k:], y1[i][k:]),
            "train_rmse_before": rmse(m[:k], yg[:k]), "train_rmse_after": rmse(m[:k], y1[i][:k]),
            "noise_sigma": cmp.problem.sigma[c],
        })
        out[c] = {key: entry[key] for key in REPORT_CHANNEL_KEYS}
    return out


def _report(cmp: _Comparison, analysis: "residuals.ResidualAnalysis", found: _Found, start_hour: float,
            min_improvement_pct: float, max_effects: int) -> dict:
    """The JSON-ready report (its keys: docs/diagnose.md, "report.json")."""
    t, nt = cmp.rec.time_s, cmp.n_train
    notes = [f"Day/night regimes assume time_s = 0 at {start_hour:g} h clock time (--start-hour)."]
    if any(h.indistinguishable_from for h in found.all_hyps if h.plausible):
        notes.append(CORRELATED_NOTE)
    notes += found.notes + cmp.rec.warnings
    ranked = sorted(found.all_hyps, key=lambda h: (h.round, h.rank_key(min_improvement_pct)))
    units = cmp.units()
    return {
        "twin": cmp.machine.source_path or cmp.machine.name,
        "recording": cmp.rec.source,
        "split": {"train_end_s": float(t[nt - 1]), "holdout_start_s": float(t[nt]),
                  "end_s": float(t[-1]), "holdout_fraction": cmp.holdout_fraction},
        "channels": _channel_scores(cmp, analysis, found.y_base),
        "windows": analysis.windows,
        "regime_effects": analysis.regime_effects[:20],
        "hypotheses": [h.as_dict() for h in ranked],
        "selected": [h.as_dict() for h in found.adopted] if found.adopted else "none",
        "unnamed": [d.as_dict(units[d.channel]) for d in found.unnamed],
        "answer": _answer(found.unnamed, found.adopted, cmp.cal_section, min_improvement_pct),
        "calibration": cmp.cal_section,
        "clock_offset": cmp.clock_offset.as_dict() if cmp.clock_offset else None,
        "augmented_twin": None,
        "criteria": {"min_holdout_improvement_pct": min_improvement_pct, "max_delta_bic": BIC_THRESHOLD,
                     "max_effects": max_effects, "multiple_testing": PROCEDURE,
                     "candidates_screened_per_round": found.tried},
        "simulations": cmp.problem.n_evals,
        "notes": notes,
    }
