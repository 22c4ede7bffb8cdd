"""Calibrate a twin's existing parameters on a recording (``thermal-comp calibrate``).

Conductances, capacities, source powers, thermo-elastic gains, sensor biases and constant
boundary temperatures move within the ranges of :mod:`calibration_bounds`, jointly, to
minimise the noise-weighted residual of every temperature and displacement channel the
twin shares with the recording on the training window (the first ``1 - holdout_fraction``);
the held-out rest is only scored. ``scipy.optimize.least_squares`` (trf, bounded) with a
Jacobian that is exact for the linear parameters (biases, gains: from the node
temperatures) and a forward difference of the exact twin for the others. Intervals come
from the Jacobian at the optimum, inflated by the residual's integrated autocorrelation
time (see docs/calibrate.md).
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
from scipy.optimize import least_squares

from thermal_twin.calibrate.bounds import Param, free_parameters, patch_machine, set_values
from thermal_twin.sim.initial_state import own_reference, start_state
from thermal_twin.sim.inputs_timeline import timeline_from_recording
from thermal_twin.machine.schema import Machine, load_machine
from thermal_twin.diagnose.fit import FitProblem, effective_samples
from thermal_twin.diagnose.statistics import recorded_resolution
from thermal_twin.diagnose.twin_eval import gap_uncertain_readings, node_states, outputs_from_states
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.runtime.engine_options import held_engine
from thermal_comp_common.bags.recording import MIN_CHANNEL_VALUES, MIN_RECORDING_ROWS
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording, column_kind, error_unit
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks

LINEAR_KINDS = ("bias", "gain")
CORR_LIMIT = 0.95
FD_STEP = 1e-4             # forward-difference step in theta (relative 1e-4 for log parameters)


class CalibrationError(ValueError):
    """Twin and recording cannot be calibrated; the message names the cause."""


@dataclass
class Estimate:
    param: Param
    value: float
    ci95: tuple[float, float]
    flags: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        p = self.param
        return {"name": p.name, "kind": p.kind, "unit": p.unit, "start": p.value0, "value": self.value,
                "ci95": list(self.ci95), "bounds": [p.lo, p.hi],
                "change_pct": (100.0 * (self.value / p.value0 - 1.0) if p.value0 else None),
                "flags": list(self.flags)}


@dataclass
class CalibrationResult:
    spec: dict                         # calibrated machine description
    estimates: list[Estimate]
    correlated: list[tuple[str, str, float]]
    channels: list[str]
    time_s: np.ndarray
    measured: dict[str, np.ndarray]
    before: dict[str, np.ndarray]
    after: dict[str, np.ndarray]
    n_train: int
    cost_before: float
    cost_after: float
    n_evals: int
    wall_s: float
    simulated_h: float
    status: str
    tau: float                         # residual autocorrelation time used for the intervals
    fixed: list[str] = field(default_factory=list)   # parameters left out, with the reason
    # readings left out of the fit and of every figure (:func:`leave_out_gap_readings`), by
    # channel (only channels with some), and the noise sigma the rule compared with
    left_out: dict[str, np.ndarray] = field(default_factory=dict)
    sigma: dict[str, float] = field(default_factory=dict)

    def scored(self, c: str) -> np.ndarray:
        """Channel ``c``'s readings as fitted and scored: NaN where left out."""
        m = self.measured[c]
        return np.where(self.left_out[c], np.nan, m) if c in self.left_out else m

    def left_out_counts(self) -> dict[str, dict]:
        """Per channel with readings left out: how many in the training and held-out windows."""
        k = self.n_train
        return {c: {"train": int(np.count_nonzero(v[:k])), "holdout": int(np.count_nonzero(v[k:])),
                    "sigma": self.sigma.get(c), "unit": "K" if column_kind(c) == "sensor" else error_unit(c)}
                for c, v in self.left_out.items()}

    def channel_table(self) -> dict[str, dict]:
        k = self.n_train
        out = {}
        for c in self.channels:
            m, b, a = self.scored(c), self.before[c], self.after[c]
            out[c] = {"train_rmse_before": rmse(m[:k], b[:k]), "train_rmse_after": rmse(m[:k], a[:k]),
                      "holdout_rmse_before": rmse(m[k:], b[k:]), "holdout_rmse_after": rmse(m[k:], a[k:])}
        return out


class TwinModel:
    """The twin as a function of theta: outputs on the shared channels and the exact
    derivatives of the linear parameters."""

    def __init__(self, spec: dict, params: list[Param], rec: Recording, channels: list[str],
                 initial_state: str = "steady"):
        self.spec0, self.params, self.rec, self.channels = spec, params, rec, channels
        self.n_evals = 0
        self.sim_steps = 0
        # ``readings``: this recording starts the twin where its sensors read (a warm start);
        # the spec written (:meth:`spec`) keeps the twin's own initial state
        self.machine0 = load_machine(spec if initial_state == "steady" else
                                     {**spec, "initial_state": start_state(spec, rec, initial_state)})
        # the inputs do not depend on any parameter: resolved once
        self.inputs = timeline_from_recording(self.machine0, rec).resolved(self.machine0)

    def spec(self, theta: np.ndarray) -> dict:
        return set_values(copy.deepcopy(self.spec0), self.params,
                          [p.value(t) for p, t in zip(self.params, theta)])

    def machine(self, theta: np.ndarray):
        """The patched machine; a forward-difference step re-patches only the one parameter
        that differs from the last Jacobian's base (the patch costs ~0.2 ms per parameter)."""
        base = getattr(self, "_base", None)
        if base is not None and base[0].shape == theta.shape:
            diff = np.flatnonzero(theta != base[0])
            if diff.size <= 2:
                return patch_machine(base[1], [self.params[i] for i in diff],
                                     [self.params[i].value(theta[i]) for i in diff])
        m = patch_machine(self.machine0, self.params, [p.value(t) for p, t in zip(self.params, theta)])
        self._base = (theta.copy(), m)
        return m

    def run(self, theta: np.ndarray, stop: int | None = None):
        m = self.machine(theta)
        net, t, X, tb = node_states(m, self.rec.time_s, self.inputs, stop)
        out = outputs_from_states(m, net, t, X, tb)
        self.n_evals += 1
        self.sim_steps += len(t)
        return np.stack([out[c] for c in self.channels]), net, X


def leave_out_gap_readings(fp: FitProblem, machine: Machine, inputs: Mapping[str, np.ndarray],
                           sigma: Mapping[str, float]) -> dict[str, np.ndarray]:
    """Leave out of ``fp`` the readings diagnose leaves out, by the same rule
    (:func:`~thermal_twin.diagnose.twin_eval.gap_uncertain_readings`): after a gap of dropped
    rows hiding an input change whose unknown instant moves the twin by more than the noise
    ``sigma`` (:func:`rule_sigma`). Returns the left-out readings by channel (only channels with some)."""
    mask = gap_uncertain_readings(machine, fp.recording.time_s, inputs, fp.channels, sigma)
    if mask is None:
        return {}
    fp.exclude(mask)
    return {c: mask[j] for j, c in enumerate(fp.channels) if mask[j].any()}


def rule_sigma(machine: Machine, rec: Recording, channels: list[str], n_train: int) -> dict[str, float]:
    """The noise the gap rule compares with, as diagnose weighs the channels: the second-difference
    estimate floored by the quantisation noise of the recorded lattice
    (:func:`~thermal_twin.diagnose.statistics.recorded_resolution`). The fit's own weights keep the
    twin's sensor resolution (unchanged on regular grids)."""
    if not channels:
        return {}
    res = {machine.sensors[s].column: machine.sensors[s].resolution for s in machine.sensors}
    return FitProblem(rec, channels, n_train, resolution=recorded_resolution(res, rec.columns, channels)).sigma


def left_out_lines(counts: Mapping[str, Mapping]) -> list[str]:
    """One sentence per channel with readings left out, from the counts of
    :meth:`CalibrationResult.left_out_counts` (so a report's text is made from its own data)."""
    return [f"{c}: {v['train'] + v['holdout']} readings left out ({v['train']} training, {v['holdout']} held-out) "
            f"after gaps of dropped rows hiding an input change, where the change's unknown instant moves "
            f"the twin by more than the channel's noise (envelope / sqrt(12) > sigma {v['sigma']:.3g} {v['unit']})"
            for c, v in counts.items()]


def pick_channels(machine, rec: Recording) -> tuple[list[str], list[str]]:
    """Shared channels with data, and the shared or twin columns that are all NaN."""
    cols = [machine.sensors[s].column for s in machine.sensors] + list(machine.errors)
    chans, empty = [], []
    for c in cols:
        if c not in rec.columns:
            continue
        if np.isfinite(np.asarray(rec.columns[c], dtype=float)).sum() >= MIN_CHANNEL_VALUES:
            chans.append(c)
        else:
            empty.append(c)
    return chans, empty


def relevant_parameters(params: list[Param], machine, channels: list[str]) -> tuple[list[Param], list[str]]:
    """Drop biases of sensors and gains of channels the recording does not have."""
    keep, fixed = [], []
    for p in params:
        if p.kind == "bias" and machine.sensors[p.path[1]].column not in channels:
            fixed.append(f"{p.name}: sensor not in the recording")
        elif p.kind == "gain" and p.path[1] not in channels:
            fixed.append(f"{p.name}: channel not in the recording")
        else:
            keep.append(p)
    return keep, fixed


def calibrate(twin, recording: Recording, holdout_fraction: float = 1 / 3,
              section: Mapping | None = None, max_nfev: int = 30,
              progress: Callable[[str], None] | None = None, prior: bool = True,
              start: Mapping[str, float] | None = None, engine: EngineSpec | None = None,
              sigma: Mapping[str, float] | None = None, initial_state: str = "steady",
              leave_out_gaps: bool = True) -> CalibrationResult:
    """Fit the free parameters of ``twin`` (path, preset, mapping or Machine) to
    ``recording``; ``section`` overrides the machine's own ``calibration`` section.
    ``prior``: pull every parameter toward its nominal value (a Gaussian prior whose 95 %
    range is the parameter's tolerance), the data weighted by their discrepancy variance
    and autocorrelation time (see docs/calibrate.md); False: plain bounded least squares.
    ``start``: values (by parameter name) to start the fit from; the prior stays at the
    twin's own values. ``engine``: where the Jacobian's finite-difference columns run
    (default serial; the same answer on every engine). BLAS runs on one thread
    (``single_thread_blas``). ``sigma``: the measurement noise of channels whose noise the
    recording cannot show (sparse probes of an error channel), by column; the others' comes
    from their second differences. ``initial_state``: ``steady`` (the twin's idle equilibrium) or
    ``readings`` (where the recording's first readings put it: a recording that starts warm).
    ``leave_out_gaps``: leave out the readings :func:`leave_out_gap_readings` names (False only
    to measure what the rule does)."""
    with single_thread_blas(), held_engine(engine) as held:
        t_start = time.perf_counter()
        jacobian = _setup(twin, recording, holdout_fraction, section, progress, sigma, initial_state, leave_out_gaps)
        jacobian.engine = held
        theta, status = fit_theta(jacobian, max_nfev, prior, start)
        return _result(jacobian, theta, status, prior, t_start)


def _setup(twin, recording: Recording, holdout_fraction: float, section: Mapping | None,
           progress: Callable[[str], None] | None, sigma: Mapping[str, float] | None = None,
           initial_state: str = "steady", leave_out_gaps: bool = True) -> "Jacobian":
    """Check twin and recording, choose the free parameters; the residual and its Jacobian."""
    if not 0.05 <= holdout_fraction <= 0.8:
        raise CalibrationError(f"holdout_fraction: {holdout_fraction!r} must be within [0.05, 0.8]")
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    spec0 = machine.to_dict()
    if section is None:
        section = spec0.get("calibration")
    channels, _ = pick_channels(machine, recording)
    if not channels:
        raise CalibrationError(f"recording {recording.source}: no channel shared with twin '{machine.name}' "
                               f"with at least {MIN_CHANNEL_VALUES} values")
    params, fixed = relevant_parameters(free_parameters(spec0, section), machine, channels)
    if not params:
        raise CalibrationError("no free parameter: the calibration section fixes everything")
    if initial_state == "readings":       # the twin starts where the recording does: so do its displacements
        recording = own_reference(machine, recording)
    n_train = int(round(len(recording) * (1.0 - holdout_fraction)))
    if n_train < MIN_RECORDING_ROWS:
        raise CalibrationError(f"recording {recording.source}: {n_train} training rows, "
                               f"need at least {MIN_RECORDING_ROWS}")
    res = {c: machine.sensors[s].resolution for s in machine.sensors
           for c in [machine.sensors[s].column]}
    given = {c: float(v) for c, v in (sigma or {}).items() if c in channels}
    if any(not (math.isfinite(v) and v > 0) for v in given.values()):
        raise CalibrationError(f"sigma: {given} must be finite and > 0 for every channel given")
    rest = [c for c in channels if c not in given]
    fp = FitProblem(recording, channels, n_train, resolution=res,
                    sigma={**(FitProblem(recording, rest, n_train, resolution=res).sigma if rest else {}), **given})
    model = TwinModel(spec0, params, recording, channels, initial_state)
    noise = {**rule_sigma(machine, recording, rest, n_train), **given}
    left_out = leave_out_gap_readings(fp, machine, model.inputs, noise) if leave_out_gaps else {}
    jacobian = Jacobian(model, fp, machine, progress)
    jacobian.fixed, jacobian.left_out, jacobian.rule_sigma = fixed, left_out, noise
    return jacobian


def fit_theta(jacobian: "Jacobian", max_nfev: int, prior: bool, start: Mapping[str, float] | None
         ) -> tuple[np.ndarray, str]:
    """(theta at the optimum, optimiser status). Two passes with the prior: the data weight
    1/(s2 tau) of the first comes from the start's residual, of the second from the first
    optimum's (the discrepancy that is left)."""
    params = jacobian.model.params
    lb, ub = jacobian.theta_bounds()
    prior_sd = (ub - lb) / 4.0 if prior else None      # tolerance = 95 % range = +-2 sd
    theta = np.zeros(len(params))
    jacobian.r_start = jacobian.resid(theta)
    for i, p in enumerate(params):
        if start and p.name in start:
            theta[i] = np.clip(p.theta(float(start[p.name])), lb[i], ub[i])
    passes = 2 if prior else 1
    weight = 1.0
    status = ""
    for k in range(passes):
        if prior:
            weight = data_weight(jacobian.resid(theta), len(jacobian.model.channels))
        fun, jac = _objective(jacobian, weight, prior_sd)
        sol = least_squares(fun, theta, jac=jac, bounds=(lb, ub), method="trf", x_scale="jac",
                            max_nfev=max(max_nfev // passes if k == 0 else max_nfev - sol.nfev, 3))
        theta, status = sol.x, sol.message
    return theta, status


def _result(jacobian: "Jacobian", theta: np.ndarray, status: str, prior: bool,
            t_start: float) -> CalibrationResult:
    """Intervals at the optimum, outputs before/after, the calibrated description; the recording
    as fitted (relative to its start when the twin starts there)."""
    model, channels = jacobian.model, jacobian.model.channels
    recording = model.rec
    params = model.params
    lb, ub = jacobian.theta_bounds()
    r = jacobian.resid(theta)
    J = jacobian(theta)
    estimates, correlated, tau = posterior_intervals(params, theta, r, J, len(channels), lb, ub,
                                            (ub - lb) / 4.0 if prior else None)
    y_before, _, _ = model.run(np.zeros(len(params)))
    y_after, _, _ = model.run(theta)
    meas = {c: np.asarray(recording.columns[c], dtype=float) for c in channels}
    spec1 = model.spec(theta)
    wall = time.perf_counter() - t_start
    n = len(recording)
    dur_h = float(recording.time_s[-1] - recording.time_s[0]) / 3600.0
    sim_h = model.sim_steps / max(n - 1, 1) * dur_h
    r_start = jacobian.r_start
    return CalibrationResult(
        spec=spec1, estimates=estimates, correlated=correlated, channels=channels,
        time_s=recording.time_s, measured=meas,
        before={c: y_before[j] for j, c in enumerate(channels)},
        after={c: y_after[j] for j, c in enumerate(channels)}, n_train=jacobian.fp.n_train,
        cost_before=0.5 * float(r_start @ r_start), cost_after=0.5 * float(r @ r),
        n_evals=model.n_evals, wall_s=wall, simulated_h=sim_h, status=status, tau=tau,
        fixed=jacobian.fixed, left_out=jacobian.left_out, sigma=dict(jacobian.rule_sigma))


def data_weight(r: np.ndarray, n_channels: int) -> float:
    """1 / (s2 tau) for the noise-weighted data residual ``r``: s2 its variance per sample
    (the discrepancy the twin leaves, usually far above the measurement noise) and tau its
    integrated autocorrelation time, so that the data count as their n_eff independent
    samples against the prior."""
    m = max(r.size, 1)
    s2 = max(float(r @ r) / m, 1e-12)
    tau = max(1.0, r.size / effective_samples(r.reshape(n_channels, -1)))
    return 1.0 / (s2 * tau)


def _objective(jacobian: "Jacobian", weight: float, prior_sd: np.ndarray | None):
    """(residual, Jacobian) of weight * |data|^2 + |theta / prior_sd|^2."""
    sw = math.sqrt(weight)

    def fun(theta):
        r = sw * jacobian.resid(theta)
        return r if prior_sd is None else np.concatenate([r, theta / prior_sd])

    def jac(theta):
        J = sw * jacobian(theta)
        return J if prior_sd is None else np.vstack([J, np.diag(1.0 / prior_sd)])
    return fun, jac


class Jacobian:
    """Data residual and its Jacobian, sharing one cache of the last twin run: exact columns
    for the linear parameters (biases, gains), a forward difference of the twin otherwise."""

    def __init__(self, model: TwinModel, fp: FitProblem, machine, progress=None):
        self.model, self.fp, self.progress = model, fp, progress
        params = model.params
        channels = model.channels
        self.w = np.array([1.0 / fp.sigma[c] for c in channels])
        self.sl = slice(0, fp.n_train, fp.stride)
        self.valid = fp._valid[:, self.sl]
        self.lin = [i for i, p in enumerate(params) if p.kind in LINEAR_KINDS]
        self.nonlin = [i for i, p in enumerate(params) if p.kind not in LINEAR_KINDS]
        chan_idx = {c: j for j, c in enumerate(channels)}
        node_idx = {nm: i for i, nm in enumerate(machine.nodes)}
        self.lin_where = {}
        for i in self.lin:
            p = params[i]
            if p.kind == "bias":
                self.lin_where[i] = (chan_idx[machine.sensors[p.path[1]].column], None)
            else:
                self.lin_where[i] = (chan_idx[p.path[1]], node_idx[p.path[3]])
        self.cache: dict = {}
        self.engine: EngineSpec | None = None
        self.fixed: list[str] = []            # parameters left out, with the reason
        self.left_out: dict[str, np.ndarray] = {}   # readings left out, by channel
        self.rule_sigma: dict[str, float] = {}       # the noise the gap rule compared with
        self.r_start: np.ndarray | None = None

    def theta_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        ps = self.model.params
        return np.array([p.theta_bounds[0] for p in ps]), np.array([p.theta_bounds[1] for p in ps])

    def __getstate__(self) -> dict:      # what a worker needs for its columns
        state = dict(self.__dict__)
        state["progress"], state["cache"], state["engine"] = None, {}, None
        return state

    def column(self, theta: np.ndarray, r0: np.ndarray, i: int) -> np.ndarray:
        """Forward difference of the residual in parameter ``i`` (one twin run)."""
        th = theta.copy()
        lo, hi = self.model.params[i].theta_bounds
        h = FD_STEP if th[i] + FD_STEP <= hi else -FD_STEP
        th[i] += h
        y, _, _ = self.model.run(th, self.fp.n_train)
        return (self.fp.train_residual(y).ravel() - r0) / h

    def resid(self, theta: np.ndarray) -> np.ndarray:
        key = theta.tobytes()
        if key not in self.cache:
            y, _, X = self.model.run(theta, self.fp.n_train)
            self.cache.clear()
            self.cache[key] = (self.fp.train_residual(y).ravel(), X)
        return self.cache[key][0]

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        r0 = self.resid(theta)
        X = self.cache[theta.tobytes()][1][self.sl]
        params = self.model.params
        J = np.zeros((r0.size, len(params)))
        ns = self.valid.shape[1]
        for i in self.lin:
            j, k = self.lin_where[i]
            d = np.zeros((len(self.w), ns))
            d[j] = -self.w[j] if k is None else -self.w[j] * (X[:, k] - X[0, k])
            J[:, i] = np.where(self.valid, d, 0.0).ravel()
        n0, steps0 = self.model.n_evals, self.model.sim_steps
        runs = steps = 0
        for k, (col, n, st) in map_tasks(_fd_column, (self, theta, r0), self.nonlin, self.engine):
            J[:, self.nonlin[k]] = col
            runs, steps = runs + n, steps + st
        self.model.n_evals, self.model.sim_steps = n0 + runs, steps0 + steps
        if self.progress is not None:
            self.progress(f"jacobian {len(params)} parameters, cost {0.5 * float(r0 @ r0):.4g}")
        return J


def _fd_column(shared: tuple, i: int) -> tuple[np.ndarray, int, int]:
    """Task of the engine: one finite-difference column (and the twin runs and steps it took)."""
    jac, theta, r0 = shared
    n0, s0 = jac.model.n_evals, jac.model.sim_steps
    col = jac.column(theta, r0, i)
    return col, jac.model.n_evals - n0, jac.model.sim_steps - s0


def posterior_intervals(params, theta, r, J, n_channels, lb, ub, prior_sd=None):
    """95 % intervals from the Jacobian: cov = s^2 tau (J^T J)^+ with s^2 = SSR/(m - p) and
    tau = m / n_eff the residual's integrated autocorrelation time (a thermal residual is
    far from white, so the plain formula would be tau times too confident). With a prior:
    the posterior cov = (J^T J / (s^2 tau) + diag(1 / prior_sd^2))^-1, and a parameter whose
    posterior sd is above half its prior sd is flagged not identified (the recording
    narrows its tolerance by less than half)."""
    m, p = J.shape
    rr = r.reshape(n_channels, -1)
    tau = max(1.0, r.size / effective_samples(rr))
    s2 = float(r @ r) / max(m - p, 1)
    JtJ = J.T @ J
    if prior_sd is not None:
        cov = np.linalg.inv(JtJ / (s2 * tau) + np.diag(1.0 / prior_sd ** 2))
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        null = sd > 0.5 * prior_sd
    else:
        cov = s2 * tau * np.linalg.pinv(JtJ, rcond=1e-12, hermitian=True)
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        # a direction the data do not see (zero singular value) gets an infinite interval
        null = np.diag(JtJ) <= 1e-18 * max(float(np.max(np.diag(JtJ))), 1e-300)
        sd[null] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    estimates = []
    for i, prm in enumerate(params):
        a, b = theta[i] - 1.96 * sd[i], theta[i] + 1.96 * sd[i]
        flags = []
        if prior_sd is not None and null[i]:
            flags.append("not identified (the recording narrows its tolerance by less than half)")
        elif a <= lb[i] and b >= ub[i]:
            flags.append("not identified (95 % interval spans its bounds)")
        if abs(theta[i] - lb[i]) <= 1e-6 * max(1.0, abs(lb[i])) or abs(theta[i] - ub[i]) <= 1e-6 * max(1.0, abs(ub[i])):
            flags.append("at bound")
        lo = prm.value(max(a, -50.0) if prm.log else a) if math.isfinite(a) else -math.inf
        hi = prm.value(min(b, 50.0) if prm.log else b) if math.isfinite(b) else math.inf
        if prm.log and not math.isfinite(a):
            lo = 0.0
        estimates.append(Estimate(prm, prm.value(theta[i]), (lo, hi), flags))
    correlated = []
    for i in range(len(params)):
        for j in range(i + 1, len(params)):
            c = corr[i, j]
            if np.isfinite(c) and abs(c) > CORR_LIMIT:
                correlated.append((params[i].name, params[j].name, float(c)))
                for k in (i, j):
                    if "correlated" not in estimates[k].flags:
                        estimates[k].flags.append("correlated")
    correlated.sort(key=lambda x: -abs(x[2]))
    return estimates, correlated, tau
