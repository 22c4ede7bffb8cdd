"""The AGP fitted on the training rows: a closed-loop row of ``thermal-comp evaluate`` on any recording.

The adaptive GP (:mod:`talc_model.agp.model`) with the training rows as its calibration phase
(:mod:`thermal_eval.evaluate.training_fit`: its calibration points are the 5-min grid samples of
those rows, charged in Q_prod): GP inputs are one medoid sensor per sensor group plus the
fast sensor, with low-pass copies; after calibration it probes on the user's budget
(:class:`thermal_eval.evaluate.adaptive.ProbingBudget`: a control measurement every
``probe_every_h``) and, as its own probings, whenever its predictive std exceeds sigma_max (at
most one per ``min_gap_s``), all within the hard cap ``max_probes_per_h``. Each probe feeds the
GP and the slow-error filter; between probes the uncertainty-weighted hold blends it with the
last measurement. Every hyper-parameter is chosen by a walk-forward inside the training rows
under the same budget. The full description (inputs, probing, selection) and the FL_THERMAL
figures: docs/fl_thermal.md. No rclpy here.
"""
from __future__ import annotations

import copy
import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from talc_model.agp.gaussian_process import ArdGaussianProcess
from talc_model.open_loop.lagged_temperature_model import lagged_features
from talc_model.open_loop.sensor_selection import fast_sensor, sensor_groups, sensor_medoids
from talc_model.loop.slow_error_filter import SlowErrorFilter, slow_error_compensation
from talc_model.probing.uncertainty_weighted_hold import measured_hold_rate, uncertainty_weighted_hold
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.metrics import mae
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.training_fit import (FOLD_STARTS, TrainingFitError, calibration_grid_rows, refused_by_cap,
                                           walk_forward_fold_rows)
from thermal_eval.evaluate.spec import EvaluationData

#: Low-pass time constant sets of the GP inputs (s): none (the thesis's static map), the
#: spindle-nose / bearing scale, and the bearing plus structure scales.
FEATURE_TAU_SETS: tuple[tuple[float, ...], ...] = ((), (1800.0,), (1800.0, 7200.0))
#: sigma_max / expected maximum error tried: the thesis's range 5-15 % (recommendation 10 %).
SIGMA_MAX_RATIOS = (0.05, 0.10, 0.15)
#: Slow-error filter grid (as for TALC fitted on the training rows).
BIAS_TAU_GRID_S = (1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 86400.0)
NOISE_RATIO_GRID = (0.0, 0.3, 1.0, 3.0)


@dataclass(frozen=True)
class AgpSchedule:
    """When the AGP fitted on the training rows probes after its calibration phase (one probing
    measures every channel)."""

    control_interval_s: float = 7200.0        # one probing every 2 h (the FL_THERMAL protocol)
    probe_duration_s: float = 95.0            # charged in Q_prod; intervals count from the cycle end
    min_sigma_probe_interval_s: float = 600.0  # sigma_max probes at most one per 10 min
    control_tolerance_um: float = 1.0         # e_tol: a control measurement further off re-optimises
    noise_guard_factor: float = 1.5           # as AgpConfig.noise_guard_factor
    max_probes_per_h: float = math.inf        # the budget's hard cap after calibration

    def __post_init__(self) -> None:
        for name in ("control_interval_s", "probe_duration_s", "min_sigma_probe_interval_s",
                     "control_tolerance_um", "noise_guard_factor", "max_probes_per_h"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not math.isnan(v) and v > 0) or \
                    (name != "max_probes_per_h" and math.isinf(v)):
                raise TrainingFitError(f"{name}: {v!r} must be a number > 0")

    @classmethod
    def from_budget(cls, budget: ProbingBudget) -> "AgpSchedule":
        """Control measurements at the user's interval, sigma_max probes ``min_gap_s`` apart at
        the earliest, the user's tolerance as e_tol, within the budget's cap."""
        return cls(budget.probe_every_h * 3600.0, budget.probe_duration_s, budget.min_gap_s, budget.tolerance_um,
                   max_probes_per_h=budget.max_probes_per_h)


@dataclass
class AgpTrajectory:
    """The GP's side of one replay (independent of the Kalman filter)."""

    mean: np.ndarray                 # N x m, the GP mean in force at each row (NaN outside the replay)
    std: np.ndarray                  # N x m, its predictive std
    probe_rows: list[int]
    probe_reasons: list[str]         # "control" or "sigma_max"
    post_probe_mean: np.ndarray      # P x m: GP mean at each probe row after the probe's update
    sigma_max_um: float
    refits_optimised: int = 0
    last_calibration_row: int = -1   # the last calibration probing before the replay
    refused_steps: int = 0           # rows at which a due probing was refused by the cap

    @property
    def measured_rows(self) -> list[int]:
        """The last calibration probing, then every probe row: where the displacement is known."""
        return [self.last_calibration_row] + list(self.probe_rows)

    @property
    def sigma_probes(self) -> int:
        return sum(r == "sigma_max" for r in self.probe_reasons)


def agp_input_sensors(temperatures: np.ndarray, names: Sequence[str], seed: int = 0, time_s: np.ndarray | None = None,
                      displacements: np.ndarray | None = None) -> list[str]:
    """One medoid per unique sensor group (WCSS elbow, thesis §5.1) of the given rows, plus (given
    ``time_s`` and ``displacements`` of the same rows) the :func:`fast_sensor` if no medoid is
    it. A medoid stands for its group's slow level and averages the spindle-near sensor's fast
    swings away, which lead the displacement's. Walk-forward inside FL_THERMAL's training rows
    (60/70/80 % folds, selected GP settings): mean MAE 2.47 um with the medoids alone, 1.59 with
    the fast sensor added."""
    groups = sensor_groups(temperatures, seed=seed)
    sensors = sensor_medoids(temperatures, groups.n_groups, list(names), seed=seed)
    if time_s is not None and displacements is not None:
        fast = fast_sensor(time_s, temperatures, displacements, list(names))
        if fast not in sensors:
            sensors.append(fast)
    return sensors


def agp_features(data: EvaluationData, sensors: Sequence[str], taus_s: Sequence[float]) -> np.ndarray:
    """GP inputs for every row, causal: medoid temperatures (change from row 0) and low-pass copies."""
    unknown = [s for s in sensors if s not in data.sensors]
    if unknown or not sensors:
        raise TrainingFitError(f"sensors: {list(sensors)!r} must be a non-empty subset of {list(data.sensors)}")
    idx = [data.sensors.index(s) for s in sensors]
    return lagged_features(data.time_s, data.temperatures[:, idx], list(taus_s))


def expected_max_error_um(Y: np.ndarray, n_calibration: int) -> float:
    """Largest |displacement| of the calibration rows, rounded up to 10 um (as the replayed agp)."""
    return 10.0 * math.ceil(max(float(np.max(np.abs(Y[:n_calibration]))), 1e-9) / 10.0)


def _new_gp(max_err: float, seed: int) -> ArdGaussianProcess:
    # the AGP's defaults (AgpConfig): kernel bounds, prior-std floor 0.25 x expected maximum error
    return ArdGaussianProcess(length_scale_bounds=(1e-2, 1e2), noise_bounds=(1e-6, 1.0),
                              min_signal_std=0.25 * max_err, max_optimize_points=600, seed=seed)


def fit_calibration_gps(X: np.ndarray, Y: np.ndarray, rows: np.ndarray, max_err: float,
                        seed: int = 0) -> list[ArdGaussianProcess]:
    """One ARD GP per channel on the calibration points (hyperparameters optimised)."""
    with single_thread_blas(openmp=True):
        return [_new_gp(max_err, seed).fit(X[rows], Y[rows, j], warm_start=False) for j in range(Y.shape[1])]


def replay_agp(time_s: np.ndarray, X: np.ndarray, Y: np.ndarray, start: int, stop: int,
               gps: Sequence[ArdGaussianProcess], cal_rows: np.ndarray, sigma_max_um: float,
               schedule: AgpSchedule) -> AgpTrajectory:
    """Replay rows [start, stop) with the GPs fitted on ``cal_rows`` (copied, not changed).

    ``Y`` is read only at ``cal_rows`` and at the probe rows the schedule picks.
    """
    t = np.asarray(time_s, dtype=float)
    n, m = Y.shape
    if not 1 <= start < stop <= n:
        raise TrainingFitError(f"start/stop: {start}..{stop} is not a range of 1..{n} rows")
    if not (math.isfinite(sigma_max_um) and sigma_max_um > 0):
        raise TrainingFitError(f"sigma_max_um: {sigma_max_um!r} must be a finite number > 0")
    if len(gps) != m or cal_rows.size < 2 or int(cal_rows.max()) >= start:
        raise TrainingFitError(f"gps/cal_rows: {len(gps)} GPs for {m} channels, calibration rows must lie before "
                             f"row {start}")
    gps = [copy.deepcopy(g) for g in gps]
    train_rows = [int(r) for r in cal_rows]
    mean = np.full((n, m), np.nan)
    std = np.full((n, m), np.nan)
    probes: list[int] = []
    reasons: list[str] = []
    post: list[np.ndarray] = []
    refits = 0

    def predict_from(k: int) -> float:
        for j, g in enumerate(gps):
            mean[k:stop, j], std[k:stop, j] = g.predict(X[k:stop])
        return max(sigma_max_um, schedule.noise_guard_factor * max(g.noise_std for g in gps))

    cycle = schedule.probe_duration_s
    refused = 0
    with single_thread_blas(openmp=True):
        threshold = predict_from(start)
        t_last = float(t[int(cal_rows[-1])])
        for k in range(start, stop):
            since = t[k] - t_last
            if since + 1e-9 >= schedule.min_sigma_probe_interval_s + cycle and np.max(std[k]) > threshold:
                reason = "sigma_max"
            elif since + 1e-9 >= schedule.control_interval_s + cycle:
                reason = "control"
            else:
                continue
            if refused_by_cap(len(probes), t[k], t[start - 1], schedule.max_probes_per_h):
                refused += 1
                continue
            if not np.all(np.isfinite(Y[k])):
                raise TrainingFitError(f"displacement: row {k} is {Y[k].tolist()!r} at a probing instant")
            miss = float(np.max(np.abs(Y[k] - mean[k])))
            train_rows.append(k)
            optimise = reason == "sigma_max" or miss > schedule.control_tolerance_um
            for j, g in enumerate(gps):
                g.fit(X[train_rows], Y[train_rows, j], warm_start=True, optimize=optimise)
            refits += int(optimise)
            probes.append(k)
            reasons.append(reason)
            t_last = float(t[k])
            if k + 1 < stop:
                threshold = predict_from(k + 1)
            post.append(np.array([float(g.predict(X[k:k + 1])[0][0]) for g in gps]))
    return AgpTrajectory(mean, std, probes, reasons, np.array(post).reshape(len(post), m), sigma_max_um, refits,
                         int(cal_rows[-1]), refused)


def best_filter(time_s, y, trajectories: Sequence[tuple[int, int, AgpTrajectory]], channel_index: int,
                tau_grid=BIAS_TAU_GRID_S, ratio_grid=NOISE_RATIO_GRID, hold_rates: Sequence[float] | None = None
                ) -> tuple[SlowErrorFilter, float, list[float]]:
    """The (tau, r) with the lowest mean MAE over the replays (start, stop, trajectory) of one
    channel; with ``hold_rates`` (one per replay) the compensation is scored after the
    :func:`uncertainty_weighted_hold` with that replay's rate."""
    j = channel_index
    rates = [math.inf] * len(trajectories) if hold_rates is None else [float(q) for q in hold_rates]
    if len(rates) != len(trajectories):
        raise TrainingFitError(f"hold_rates: {len(rates)} given for {len(trajectories)} replays")
    best: tuple[float, SlowErrorFilter | None, list[float]] = (math.inf, None, [])
    for tau, ratio in itertools.product(tau_grid, ratio_grid):
        flt = SlowErrorFilter(float(tau), float(ratio))
        errs = []
        for (start, stop, tr), q in zip(trajectories, rates):
            c = slow_error_compensation(time_s, y, tr.mean[:, j], tr.probe_rows, tr.post_probe_mean[:, j], start,
                                        stop, flt)
            c = uncertainty_weighted_hold(time_s, y, c, tr.std[:, j], tr.measured_rows, start, stop, q)
            errs.append(mae(y[start:stop], c[start:stop]))
        if float(np.mean(errs)) < best[0]:
            best = (float(np.mean(errs)), flt, errs)
    assert best[1] is not None
    return best[1], best[0], best[2]


@dataclass
class TrainingFitAgp:
    compensation: dict[str, np.ndarray]
    gp_mean: dict[str, np.ndarray]
    trajectory: AgpTrajectory
    filters: dict[str, SlowErrorFilter]
    hold_rates: dict[str, float]
    sensors: list[str]
    feature_taus_s: tuple[float, ...]
    sigma_max_ratio: float
    calibration_rows: list[int]               # the charged calibration probings (grid samples)
    schedule: AgpSchedule
    walk_forward: dict[str, Any] = field(default_factory=dict)

    def settings(self) -> dict[str, Any]:
        """What was chosen and what the probings were, for the row's JSON."""
        tr = self.trajectory
        return {"inputs": list(self.sensors), "feature_taus_s": list(self.feature_taus_s),
                "sigma_max_ratio": self.sigma_max_ratio, "sigma_max_um": round(tr.sigma_max_um, 3),
                "sigma_max_probings": tr.sigma_probes, "control_probings": len(tr.probe_rows) - tr.sigma_probes,
                "filters": {ch: {"bias_time_constant_h": round(f.bias_time_constant_s / 3600.0, 3),
                                 "noise_ratio": f.noise_ratio,
                                 "hold_rate_um2_per_h": "inf" if math.isinf(self.hold_rates[ch])
                                 else round(self.hold_rates[ch], 2)} for ch, f in self.filters.items()},
                "walk_forward": self.walk_forward}


def _training_fit_trajectories(data: EvaluationData, Y: np.ndarray, n_cal: int, stop: int, taus, ratios,
                               schedule: AgpSchedule, seed: int, progress) -> dict[tuple, tuple[AgpTrajectory, list[str]]]:
    """Trajectories of every (taus, ratio) for calibration rows 0..n_cal-1, replay n_cal..stop-1."""
    sensors = agp_input_sensors(data.temperatures[:n_cal], data.sensors, seed=seed, time_s=data.time_s[:n_cal],
                                displacements=Y[:n_cal])
    cal = calibration_grid_rows(data.time_s, n_cal)
    max_err = expected_max_error_um(Y, n_cal)
    out = {}
    for tau_set in taus:
        X = agp_features(data, sensors, tau_set)
        gps = fit_calibration_gps(X, Y, cal, max_err, seed)
        for ratio in ratios:
            out[(tuple(tau_set), float(ratio))] = (replay_agp(data.time_s, X, Y, n_cal, stop, gps, cal,
                                                              ratio * max_err, schedule), sensors)
            if progress is not None:
                progress()
    return out


def _select(candidates: list, target_um: float) -> tuple[tuple, dict[str, SlowErrorFilter], bool]:
    """Among the (key, MAE per channel, probings, filters) meeting ``target_um`` on every channel
    the one with the fewest probings; if none does, the lowest channel-mean MAE."""
    meeting = [c for c in candidates if max(c[1].values()) <= target_um]
    if meeting:
        key, _, _, filters = min(meeting, key=lambda c: (c[2], float(np.mean(list(c[1].values())))))
    else:
        key, _, _, filters = min(candidates, key=lambda c: float(np.mean(list(c[1].values()))))
    return key, filters, bool(meeting)


def run_training_fit_agp(data: EvaluationData, budget: ProbingBudget, *,
                         feature_tau_sets: Sequence[Sequence[float]] = FEATURE_TAU_SETS,
                         sigma_max_ratios: Sequence[float] = SIGMA_MAX_RATIOS, fold_starts: Sequence[float] = FOLD_STARTS,
                         tau_grid=BIAS_TAU_GRID_S, ratio_grid=NOISE_RATIO_GRID, hold: bool = True,
                         seed: int = 0, progress: Callable[[], Any] | None = None) -> TrainingFitAgp:
    """Walk-forward selection inside the training rows, then the fit on all of them and
    the replay of the rows after under ``budget`` (module docstring). The selection's target is
    the budget's tolerance."""
    n = data.split.n_train
    if not feature_tau_sets or not sigma_max_ratios:
        raise TrainingFitError("feature_tau_sets / sigma_max_ratios: need at least one candidate each")
    bad = [r for r in sigma_max_ratios if not (isinstance(r, (int, float)) and 0 < r < 1)]
    if bad:
        raise TrainingFitError(f"sigma_max_ratios: {bad!r} must lie in (0, 1)")
    channels = data.channels
    schedule = AgpSchedule.from_budget(budget)
    Y = np.column_stack([data.displacement_um[ch] for ch in channels])
    folds = [(k, _training_fit_trajectories(data, Y, k, n, feature_tau_sets, sigma_max_ratios, schedule, seed, progress))
             for k in walk_forward_fold_rows(fold_starts, n)]
    scores: dict[str, Any] = {}
    candidates = []
    # each fold's hold rate per channel, from that fold's calibration rows (same for every key)
    fold_rates = {ch: [measured_hold_rate(data.time_s, Y[:, j], k) for k, _ in folds] if hold else None
                  for j, ch in enumerate(channels)}
    for key in folds[0][1]:
        per_ch, filters = {}, {}
        for j, ch in enumerate(channels):
            filters[ch], per_ch[ch], _ = best_filter(data.time_s, Y[:, j], [(k, n, fl[key][0]) for k, fl in folds],
                                                     j, tau_grid, ratio_grid, fold_rates[ch])
        probings = float(np.mean([len(fl[key][0].probe_rows) for _, fl in folds]))
        label = f"taus={'+'.join(f'{t / 3600:g}h' for t in key[0]) or 'none'},sigma_ratio={key[1]:g}"
        scores[label] = {"mae_um": {ch: round(v, 3) for ch, v in per_ch.items()}, "mean_probings": round(probings, 1)}
        candidates.append((key, per_ch, probings, filters))
    key, filters, met = _select(candidates, budget.tolerance_um)
    traj, sensors = _training_fit_trajectories(data, Y, n, len(data), [key[0]], [key[1]], schedule, seed, progress)[key]
    comp, gp_mean, hold_rates = {}, {}, {}
    for j, ch in enumerate(channels):
        hold_rates[ch] = measured_hold_rate(data.time_s, Y[:, j], n) if hold else math.inf
        c = slow_error_compensation(data.time_s, Y[:, j], traj.mean[:, j], traj.probe_rows,
                                    traj.post_probe_mean[:, j], n, len(data), filters[ch])
        comp[ch] = uncertainty_weighted_hold(data.time_s, Y[:, j], c, traj.std[:, j], traj.measured_rows, n,
                                             len(data), hold_rates[ch])
        gp_mean[ch] = traj.mean[:, j]
    return TrainingFitAgp(comp, gp_mean, traj, filters, hold_rates, sensors, key[0], key[1],
                         [int(r) for r in calibration_grid_rows(data.time_s, n)], schedule,
                         {"scores": scores, "met_tolerance_on_every_channel": met})
