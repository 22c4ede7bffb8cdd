"""Calibrate a twin on several recordings (runs) at once (``thermal-comp calibrate --recording A B ...``).

Every run is simulated alone from its own initial state (the twin's steady state at the run's
first inputs, its displacements relative to the run's first row: exactly what
:func:`~thermal_twin.calibrate.fit.calibrate` does for one recording), and the residuals of all
training runs enter one least-squares fit with the same prior, weights and intervals. The split
is by run (the folds of :mod:`thermal_comp_common.run_splits`, the grammar of ``evaluate``): the
held-out runs are never fitted, so their figures are out of sample. A fit is the runs laid end
to end (training runs first) as one :class:`~thermal_twin.calibrate.fit.CalibrationResult`, whose
train / held-out RMSE are the pooled figures, plus every run's own RMSE before and after. Several
folds (leave one run out, by unit): one fit per fold, the held-out figures pooled over the folds,
the parameters' spread across folds, and a last fit on all runs as the twin written.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from thermal_twin.calibrate.bounds import free_parameters
from thermal_twin.calibrate.fit import (CalibrationError, CalibrationResult, Jacobian, TwinModel, fit_theta,
                                        leave_out_gap_readings, pick_channels, posterior_intervals,
                                        relevant_parameters, rule_sigma)
from thermal_twin.diagnose.fit import FitProblem
from thermal_twin.machine.schema import Machine, load_machine
from thermal_twin.sim.initial_state import own_reference
from thermal_comp_common.bags.recording import MIN_CHANNEL_VALUES, MIN_RECORDING_ROWS
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.engine_options import held_engine
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_comp_common.run_splits import RunFold


#: a parameter whose estimates across folds span more than this share of its allowed range is
#: not pinned down by the runs (it moves with which runs are fitted)
SPREAD_SHARE = 0.25


@dataclass
class RunsCalibration:
    """The fit over several runs: ``result`` is the runs laid end to end (training runs first;
    its channel table gives the pooled figures), ``runs`` every run's own figures."""

    result: CalibrationResult
    runs: list[dict] = field(default_factory=list)


@dataclass
class FoldsCalibration:
    """Calibrations over the folds of a split by run: per fold its runs, figures and parameters
    (``folds``), the held-out figures pooled over the folds (``pooled``), every parameter's
    spread across the folds (``spread``) and the fit written as the twin (``written``, from
    ``written_from``: 'all runs' when there are several folds, else the one fold's name)."""

    folds: list[dict]
    pooled: dict[str, dict]
    spread: list[dict]
    written: RunsCalibration
    written_from: str


def check_same_columns(runs: Sequence[Recording], names: Sequence[str]) -> None:
    """Refuse a run whose columns differ from the first run's, naming its file and the columns."""
    ref = set(runs[0].columns)
    for rec, name in zip(runs[1:], names[1:]):
        cols = set(rec.columns)
        if cols != ref:
            missing, extra = sorted(ref - cols), sorted(cols - ref)
            what = "; ".join(s for s in (f"missing {', '.join(missing)}" if missing else "",
                                         f"extra {', '.join(extra)}" if extra else "") if s)
            raise CalibrationError(f"run {name!r} ({rec.source}): its columns differ from run {names[0]!r} "
                                   f"({runs[0].source}): {what}")


def holdout_indices(names: Sequence[str], holdout: int | str | Sequence[str] | None) -> list[int]:
    """Which runs are held out: ``None`` the last third (at least one), an integer the last K,
    names (a list or 'a,b') those runs; at least one run must stay for training."""
    n = len(names)
    if holdout is None:
        holdout = max(1, round(n / 3))
    if isinstance(holdout, str):
        holdout = int(holdout) if holdout.strip().isdigit() else [h.strip() for h in holdout.split(",") if h.strip()]
    if isinstance(holdout, int):
        if not 1 <= holdout < n:
            raise CalibrationError(f"holdout runs: {holdout} must be within [1, {n - 1}] for {n} runs")
        return list(range(n - holdout, n))
    unknown = [h for h in holdout if h not in names]
    if unknown:
        raise CalibrationError(f"holdout runs: {unknown[0]!r} is not a run (runs: {', '.join(names)})")
    idx = sorted({names.index(h) for h in holdout})
    if not idx or len(idx) == n:
        raise CalibrationError(f"holdout runs: {','.join(holdout)!r} must leave at least one of {n} runs "
                               "for training and hold out at least one")
    return idx


class _RunsJacobian:
    """The residual and Jacobian of several runs as one: per channel, the runs' samples one
    after the other (channel-major, as :func:`~thermal_twin.calibrate.fit.data_weight` and the
    intervals read a residual)."""

    def __init__(self, parts: list[Jacobian], progress: Callable[[str], None] | None):
        self.parts, self.progress = parts, progress
        self.model = parts[0].model
        self.n_ch, self.n_par = len(self.model.channels), len(self.model.params)
        self.r_start: np.ndarray | None = None

    def theta_bounds(self):
        return self.parts[0].theta_bounds()

    def resid(self, theta: np.ndarray) -> np.ndarray:
        return np.concatenate([p.resid(theta).reshape(self.n_ch, -1) for p in self.parts], axis=1).ravel()

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        J = np.concatenate([p(theta).reshape(self.n_ch, -1, self.n_par) for p in self.parts], axis=1)
        if self.progress is not None:
            r = self.resid(theta)
            self.progress(f"jacobian {self.n_par} parameters on {len(self.parts)} runs, cost {0.5 * float(r @ r):.4g}")
        return J.reshape(-1, self.n_par)


def _shared_channels(machine: Machine, runs: Sequence[Recording], names: Sequence[str]) -> list[str]:
    """Channels the twin shares with every run, with data in every run."""
    picked = [pick_channels(machine, rec)[0] for rec in runs]
    chans = [c for c in picked[0] if all(c in p for p in picked[1:])]
    if not chans:
        raise CalibrationError(f"runs {', '.join(names)}: no channel shared with twin '{machine.name}' with at "
                               f"least {MIN_CHANNEL_VALUES} values in every run")
    return chans


def holdout_fold(names: Sequence[str], holdout: int | str | Sequence[str] | None) -> RunFold:
    """``--holdout-runs`` as a fold of the split grammar: the runs :func:`holdout_indices` names
    are the test runs, every other run trains."""
    held = holdout_indices(names, holdout)
    return RunFold("held out " + ", ".join(names[i] for i in held),
                   tuple(i for i in range(len(names)) if i not in held), (), tuple(held))


def _prepared(twin, runs: Sequence[Recording], names: Sequence[str] | None) -> tuple[Machine, list, list[str]]:
    """The machine, every run relative to its own start, the run names; bad runs refused."""
    names = list(names) if names is not None else [r.source or f"run{i}" for i, r in enumerate(runs)]
    if len(runs) < 2 or len(names) != len(runs):
        raise CalibrationError(f"calibrate_runs: {len(runs)} runs and {len(names)} names; give at least 2 runs")
    check_same_columns(runs, names)
    for rec, name in zip(runs, names):
        if len(rec) < MIN_RECORDING_ROWS:
            raise CalibrationError(f"run {name!r} ({rec.source}): {len(rec)} rows, need at least {MIN_RECORDING_ROWS}")
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    return machine, [own_reference(machine, rec) for rec in runs], names


def calibrate_runs(twin, runs: Sequence[Recording], names: Sequence[str] | None = None,
                   holdout: int | str | Sequence[str] | None = None, section: Mapping | None = None,
                   max_nfev: int = 30, progress: Callable[[str], None] | None = None, prior: bool = True,
                   engine: EngineSpec | None = None, fold: RunFold | None = None,
                   initial_state: str = "steady", sigma: Mapping[str, float] | None = None) -> RunsCalibration:
    """Fit the free parameters of ``twin`` to the training runs of ``runs`` together (every run
    from its own initial state) and score every run; the split is ``fold`` (the grammar of
    :mod:`thermal_comp_common.run_splits`) or else ``holdout`` as :func:`holdout_indices`.
    Prior, weights, bounds and intervals as :func:`~thermal_twin.calibrate.fit.calibrate`; the
    noise sigma of a channel is the median over the training runs of each run's own, or ``sigma``'s
    for the channels it names (sparse probes of an error channel, as for one recording)."""
    machine, runs, names = _prepared(twin, runs, names)
    fold = holdout_fold(names, holdout) if fold is None else fold
    with single_thread_blas(), held_engine(engine) as eng:
        return _fit_fold(machine, runs, names, fold, section, max_nfev, progress, prior, eng, initial_state,
                         sigma)


def calibrate_folds(twin, runs: Sequence[Recording], names: Sequence[str] | None, folds: Sequence[RunFold],
                    section: Mapping | None = None, max_nfev: int = 30, progress: Callable[[str], None] | None = None,
                    prior: bool = True, engine: EngineSpec | None = None,
                    initial_state: str = "steady") -> FoldsCalibration:
    """One calibration per fold (as :func:`calibrate_runs`); the held-out figures pooled over the
    folds and the parameters' spread across them. Several folds: the twin written is one more fit,
    on all runs (the folds measured how such a fit does on runs it has not seen); one fold: that
    fold's fit. Several folds on an engine of several workers run as its tasks, each fit serial
    inside; else the fits run one after the other, their Jacobian columns on ``engine``. The
    answer is the same either way."""
    machine, runs, names = _prepared(twin, runs, names)
    say = progress or (lambda _s: None)
    jobs = list(folds) + ([RunFold("all runs", tuple(range(len(runs))), (), ())] if len(folds) > 1 else [])
    for k, f in enumerate(folds):
        say(f"fold {k + 1}/{len(folds)} ({f.name}): fitting {', '.join(names[i] for i in f.train)}; "
            f"scoring {', '.join(names[i] for _, i in f.held_out())}")
    if len(jobs) > 1:
        say(f"all {len(runs)} runs: fitting the twin written")
    fits: list[RunsCalibration | None] = [None] * len(jobs)
    with single_thread_blas(), held_engine(engine) as eng:
        if len(jobs) > 1 and (eng.kind == "dask" or eng.workers > 1):
            done = map_tasks(_fold_task, (machine, runs, names, section, max_nfev, prior, initial_state), jobs, eng)
        else:
            done = ((k, _fit_fold(machine, runs, names, f, section, max_nfev, progress, prior, eng, initial_state))
                    for k, f in enumerate(jobs))
        for k, rc in done:
            fits[k] = rc
            table = rc.result.channel_table()
            what = f"fold {k + 1}/{len(folds)}" if k < len(folds) else "all runs"
            say(f"{what} done in {rc.result.wall_s:.1f} s; " + ("held-out RMSE " + ", ".join(
                f"{c} {v['holdout_rmse_before']:.3g} -> {v['holdout_rmse_after']:.3g}"
                for c, v in list(table.items())[:4]) if k < len(folds) else "twin written"))
    per_fold = fits[:len(folds)]
    return FoldsCalibration(folds=[_fold_summary(f, rc) for f, rc in zip(folds, per_fold)],
                            pooled=pooled_held_out(per_fold), spread=parameter_spread(per_fold, fits[-1]),
                            written=fits[-1], written_from="all runs" if len(folds) > 1 else folds[0].name)


def _fold_task(shared, fold: RunFold) -> RunsCalibration:
    """One fold's fit on an engine's worker (its Jacobian serial: the folds are the parallelism)."""
    machine, runs, names, section, max_nfev, prior, initial_state = shared
    return _fit_fold(machine, runs, names, fold, section, max_nfev, None, prior, EngineSpec(), initial_state)


def _fold_summary(fold: RunFold, rc: RunsCalibration) -> dict:
    r = rc.result
    return {"name": fold.name, "train": [x["name"] for x in rc.runs if x["role"] == "train"],
            "held_out": [x["name"] for x in rc.runs if x["role"] != "train"],
            "channels": r.channel_table(), "runs": rc.runs, "wall_s": r.wall_s, "status": r.status,
            "cost_before": r.cost_before, "cost_after": r.cost_after,
            "parameters": {e.param.name: {"value": e.value, "ci95": list(e.ci95)} for e in r.estimates}}


def pooled_held_out(fits: Sequence[RunsCalibration]) -> dict[str, dict]:
    """Per channel, the held-out RMSE before/after over every held-out run of every fold (each
    run's figure from the fold that held it out): sqrt(sum n rmse^2 / sum n) over the runs."""
    held = [x for rc in fits for x in rc.runs if x["role"] != "train"]
    out = {}
    for c in (held[0]["channels"] if held else {}):
        n = np.array([x["channels"][c]["n"] for x in held], dtype=float)
        row = {"n": int(n.sum()), "runs": len(held)}
        for key in ("rmse_before", "rmse_after"):
            v = np.array([x["channels"][c][key] for x in held], dtype=float)
            ok = (n > 0) & np.isfinite(v)
            row[key] = float(np.sqrt(np.sum(n[ok] * v[ok] ** 2) / n[ok].sum())) if ok.any() else float("nan")
        out[c] = row
    return out


def parameter_spread(fits: Sequence[RunsCalibration], written: RunsCalibration) -> list[dict]:
    """Every parameter's estimate per fold and how far it moves between folds, as a share of its
    allowed range (on the fitted scale: log for factor kinds); ``moves`` when the share exceeds
    :data:`SPREAD_SHARE` (the runs do not pin it down), ``disjoint`` when the folds' 95 %
    intervals have no common point (each fold is sure of a different value). Largest share first."""
    if len(fits) < 2:
        return []
    out = []
    for j, e in enumerate(written.result.estimates):
        p = e.param
        per = [rc.result.estimates[j] for rc in fits]
        theta = [math.log(x.value / p.value0) if p.log else x.value - p.value0 for x in per]
        lo, hi = p.theta_bounds
        share = (max(theta) - min(theta)) / (hi - lo) if hi > lo else 0.0
        out.append({"name": p.name, "unit": p.unit, "values": [x.value for x in per], "written": e.value,
                    "share_of_range": share, "moves": share > SPREAD_SHARE,
                    "disjoint": max(x.ci95[0] for x in per) > min(x.ci95[1] for x in per)})
    return sorted(out, key=lambda d: -d["share_of_range"])


def _fit_fold(machine: Machine, runs: list, names: list[str], fold: RunFold, section, max_nfev: int,
              progress, prior: bool, eng, initial_state: str = "steady",
              sigma_given: Mapping[str, float] | None = None) -> RunsCalibration:
    """One fit over the fold's training runs (already relative to their own start); every run of
    the fold scored. A fold without held-out runs is the fit on all its runs (in sample only)."""
    held = [i for _, i in fold.held_out()]
    train = list(fold.train)
    if not train:
        raise CalibrationError(f"runs split {fold.name!r}: no training run")
    order = train + held
    t_start = time.perf_counter()
    spec0 = machine.to_dict()
    section = spec0.get("calibration") if section is None else section
    channels = _shared_channels(machine, runs, names)
    params, fixed = relevant_parameters(free_parameters(spec0, section), machine, channels)
    if not params:
        raise CalibrationError("no free parameter: the calibration section fixes everything")
    res = {machine.sensors[s].column: machine.sensors[s].resolution for s in machine.sensors}
    sig = [FitProblem(runs[i], channels, len(runs[i]), resolution=res).sigma for i in train]
    sigma = {c: float(np.median([s[c] for s in sig])) for c in channels}
    sigma.update({c: float(v) for c, v in (sigma_given or {}).items() if c in channels})
    models = {i: TwinModel(spec0, params, runs[i], channels, initial_state) for i in order}
    problems = {i: FitProblem(runs[i], channels, len(runs[i]), sigma=sigma, resolution=res) for i in order}
    # every run, fitted or held out, leaves out the readings diagnose would, with the training runs'
    # median noise as the rule sees it
    rule = [rule_sigma(machine, runs[i], channels, len(runs[i])) for i in train]
    noise = {c: float(np.median([s[c] for s in rule])) for c in channels}
    noise.update({c: float(v) for c, v in (sigma_given or {}).items() if c in channels})
    left_out = {i: leave_out_gap_readings(problems[i], machine, models[i].inputs, noise) for i in order}
    parts = []
    for i in train:
        part = Jacobian(models[i], problems[i], machine)
        part.engine = eng
        parts.append(part)
    jac = _RunsJacobian(parts, progress)
    theta, status = fit_theta(jac, max_nfev, prior, None)
    r, J = jac.resid(theta), jac(theta)
    lb, ub = jac.theta_bounds()
    estimates, correlated, tau = posterior_intervals(params, theta, r, J, len(channels), lb, ub,
                                                     (ub - lb) / 4.0 if prior else None)
    before = {i: models[i].run(np.zeros(len(params)))[0] for i in order}
    after = {i: models[i].run(theta)[0] for i in order}
    result = _end_to_end(runs, order, len(train), channels, before, after)
    result.left_out = {c: np.concatenate([left_out[i].get(c, np.zeros(len(runs[i]), bool)) for i in order])
                       for c in channels if any(c in left_out[i] for i in order)}
    result.sigma = noise
    result.spec, result.estimates = models[train[0]].spec(theta), estimates
    result.correlated, result.fixed = correlated, fixed
    result.cost_before, result.cost_after = 0.5 * float(jac.r_start @ jac.r_start), 0.5 * float(r @ r)
    result.n_evals = sum(m.n_evals for m in models.values())
    result.simulated_h = sum(m.sim_steps / max(len(runs[i]) - 1, 1) * _hours(runs[i]) for i, m in models.items())
    result.status, result.tau, result.wall_s = status, tau, time.perf_counter() - t_start
    roles = {i: "validation" for i in fold.validation} | {i: "holdout" for i in fold.test}
    table = [_run_figures(names[i], runs[i], roles.get(i, "train"), channels, before[i], after[i], left_out[i])
             for i in order]
    return RunsCalibration(result, table)


def _hours(rec: Recording) -> float:
    return float(rec.time_s[-1] - rec.time_s[0]) / 3600.0


def _end_to_end(runs, order, n_train_runs, channels, before, after) -> CalibrationResult:
    """The runs in ``order`` laid end to end on one time axis (each run's own time from its start,
    one median step between runs); ``n_train`` the training runs' rows."""
    t_parts, off = [], 0.0
    for i in order:
        t = np.asarray(runs[i].time_s, dtype=float)
        t_parts.append(t - t[0] + off)
        off = t_parts[-1][-1] + float(np.median(np.diff(t)))
    cat = lambda per_run: {c: np.concatenate([per_run(i, j) for i in order]) for j, c in enumerate(channels)}
    return CalibrationResult(
        spec={}, estimates=[], correlated=[], channels=list(channels), time_s=np.concatenate(t_parts),
        measured=cat(lambda i, j: np.asarray(runs[i].columns[channels[j]], dtype=float)),
        before=cat(lambda i, j: before[i][j]), after=cat(lambda i, j: after[i][j]),
        n_train=sum(len(runs[i]) for i in order[:n_train_runs]), cost_before=0.0, cost_after=0.0,
        n_evals=0, wall_s=0.0, simulated_h=0.0, status="", tau=1.0)


def _run_figures(name: str, rec: Recording, role: str, channels, y_before, y_after,
                 left_out: Mapping[str, np.ndarray] | None = None) -> dict:
    """One run's RMSE per channel before and after the calibration; ``n`` the samples scored
    (recorded, not left out, and simulated finite), so runs pool as sqrt(sum n rmse^2 / sum n)."""
    chans = {}
    for j, c in enumerate(channels):
        m = np.asarray(rec.columns[c], dtype=float)
        if left_out and c in left_out:
            m = np.where(left_out[c], np.nan, m)
        n = int(np.count_nonzero(np.isfinite(m) & np.isfinite(y_after[j])))
        chans[c] = {"rmse_before": rmse(m, y_before[j]), "rmse_after": rmse(m, y_after[j]), "n": n}
    return {"name": name, "source": rec.source, "role": role, "rows": len(rec), "hours": _hours(rec),
            "channels": chans}
