"""Calibrate a twin on several recordings (runs) at once (``thermal-comp calibrate --recording A B ...``).

Every run is simulated alone from its own initial state (the twin's steady state at the run's
first inputs, its displacements relative to the run's first row: exactly what
:func:`~thermal_twin.calibrate.fit.calibrate` does for one recording), and the residuals of all
training runs enter one least-squares fit with the same prior, weights and intervals. The split
is by run: the held-out runs are never fitted, so their figures are out of sample. The result
is the runs laid end to end (training runs first) as one
:class:`~thermal_twin.calibrate.fit.CalibrationResult`, whose train / held-out RMSE are the
pooled figures, plus every run's own RMSE before and after.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from thermal_twin.calibrate.bounds import free_parameters
from thermal_twin.calibrate.fit import (CalibrationError, CalibrationResult, Jacobian, TwinModel, fit_theta,
                                        pick_channels, posterior_intervals, relevant_parameters)
from thermal_twin.diagnose.fit import FitProblem
from thermal_twin.machine.schema import Machine, load_machine
from thermal_comp_common.bags.recording import MIN_CHANNEL_VALUES, MIN_RECORDING_ROWS
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.engine_options import held_engine
from thermal_comp_common.runtime.task_engine import EngineSpec


@dataclass
class RunsCalibration:
    """The fit over several runs: ``result`` is the runs laid end to end (training runs first;
    its channel table gives the pooled figures), ``runs`` every run's own figures."""

    result: CalibrationResult
    runs: list[dict] = field(default_factory=list)


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


def calibrate_runs(twin, runs: Sequence[Recording], names: Sequence[str] | None = None,
                   holdout: int | str | Sequence[str] | None = None, section: Mapping | None = None,
                   max_nfev: int = 30, progress: Callable[[str], None] | None = None, prior: bool = True,
                   engine: EngineSpec | None = None) -> RunsCalibration:
    """Fit the free parameters of ``twin`` to the training runs of ``runs`` together (every run
    from its own initial state) and score every run; ``holdout`` as :func:`holdout_indices`.
    Prior, weights, bounds and intervals as :func:`~thermal_twin.calibrate.fit.calibrate`; the
    noise sigma of a channel is the median over the training runs of each run's own."""
    names = list(names) if names is not None else [r.source or f"run{i}" for i, r in enumerate(runs)]
    if len(runs) < 2 or len(names) != len(runs):
        raise CalibrationError(f"calibrate_runs: {len(runs)} runs and {len(names)} names; give at least 2 runs")
    check_same_columns(runs, names)
    for rec, name in zip(runs, names):
        if len(rec) < MIN_RECORDING_ROWS:
            raise CalibrationError(f"run {name!r} ({rec.source}): {len(rec)} rows, need at least {MIN_RECORDING_ROWS}")
    held = holdout_indices(names, holdout)
    order = [i for i in range(len(runs)) if i not in held] + held
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    runs = [own_reference(machine, rec) for rec in runs]
    with single_thread_blas(), held_engine(engine) as eng:
        t_start = time.perf_counter()
        spec0 = machine.to_dict()
        section = spec0.get("calibration") if section is None else section
        channels = _shared_channels(machine, runs, names)
        params, fixed = relevant_parameters(free_parameters(spec0, section), machine, channels)
        if not params:
            raise CalibrationError("no free parameter: the calibration section fixes everything")
        res = {machine.sensors[s].column: machine.sensors[s].resolution for s in machine.sensors}
        train = [i for i in order if i not in held]
        sig = [FitProblem(runs[i], channels, len(runs[i]), resolution=res).sigma for i in train]
        sigma = {c: float(np.median([s[c] for s in sig])) for c in channels}
        models = [TwinModel(spec0, params, rec, channels) for rec in runs]
        parts = []
        for i in train:
            part = Jacobian(models[i], FitProblem(runs[i], channels, len(runs[i]), sigma=sigma, resolution=res),
                            machine)
            part.engine = eng
            parts.append(part)
        jac = _RunsJacobian(parts, progress)
        theta, status = fit_theta(jac, max_nfev, prior, None)
        r, J = jac.resid(theta), jac(theta)
        lb, ub = jac.theta_bounds()
        estimates, correlated, tau = posterior_intervals(params, theta, r, J, len(channels), lb, ub,
                                                (ub - lb) / 4.0 if prior else None)
        before = [models[i].run(np.zeros(len(params)))[0] for i in range(len(runs))]
        after = [models[i].run(theta)[0] for i in range(len(runs))]
        result = _end_to_end(runs, order, len(train), channels, before, after)
        result.spec, result.estimates = models[0].spec(theta), estimates
        result.correlated, result.fixed = correlated, fixed
        result.cost_before, result.cost_after = 0.5 * float(jac.r_start @ jac.r_start), 0.5 * float(r @ r)
        result.n_evals = sum(m.n_evals for m in models)
        result.simulated_h = sum(m.sim_steps / max(len(rec) - 1, 1) * _hours(rec) for m, rec in zip(models, runs))
        result.status, result.tau, result.wall_s = status, tau, time.perf_counter() - t_start
    table = [_run_figures(names[i], runs[i], "holdout" if i in held else "train", channels, before[i], after[i])
             for i in order]
    return RunsCalibration(result, table)


def own_reference(machine: Machine, rec: Recording) -> Recording:
    """The run with every displacement channel relative to its first finite value: the twin's
    displacements start at 0 with every run, so the run's must too (a run cut from a longer
    recording starts wherever the machine had drifted to)."""
    out = rec.slice(0, len(rec))
    for c in machine.errors:
        if c in out.columns:
            v = np.asarray(out.columns[c], dtype=float)
            ok = np.flatnonzero(np.isfinite(v))
            if ok.size:
                out.columns[c] = v - v[ok[0]]
    return out


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


def _run_figures(name: str, rec: Recording, role: str, channels, y_before, y_after) -> dict:
    """One run's RMSE per channel before and after the calibration."""
    chans = {}
    for j, c in enumerate(channels):
        m = np.asarray(rec.columns[c], dtype=float)
        chans[c] = {"rmse_before": rmse(m, y_before[j]), "rmse_after": rmse(m, y_after[j])}
    return {"name": name, "source": rec.source, "role": role, "rows": len(rec), "hours": _hours(rec),
            "channels": chans}
