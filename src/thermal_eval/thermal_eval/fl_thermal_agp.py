"""AGP on FL_THERMAL calibrated on the training rows: 2-h probes plus sigma_max recalibrations.

The adaptive GP (:mod:`talc_model.agp`) with the training rows as its calibration phase: GP
inputs are medoid and fast sensors with low-pass copies; it probes every 2 h and whenever its
predictive std exceeds sigma_max, each probe feeding the GP and the slow-error filter, and
between probes the uncertainty-weighted hold blends it with the last measurement. Every
hyper-parameter is chosen by a walk-forward inside the training rows. The full description
(inputs, probing, what a probe does, the selection): docs/fl_thermal.md. No rclpy here.
"""
from __future__ import annotations

import copy
import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from talc_model.gaussian_process import ArdGaussianProcess
from talc_model.lagged_temperature_model import lagged_features
from talc_model.probe_update import q_prod_pct
from talc_model.sensor_selection import fast_sensor, sensor_groups, sensor_medoids
from talc_model.slow_error_filter import SlowErrorFilter, slow_error_compensation
from talc_model.uncertainty_weighted_hold import measured_hold_rate, uncertainty_weighted_hold
from threadpoolctl import threadpool_limits
from thermal_eval.fl_thermal_data import CHANNELS, SENSORS, FlThermalData, FlThermalError, Splits, mae, walk_forward_fold_rows

#: Low-pass time constant sets of the GP inputs (s): none (the thesis's static map), the
#: spindle-nose / bearing scale, and the bearing plus structure scales.
FEATURE_TAU_SETS: tuple[tuple[float, ...], ...] = ((), (1800.0,), (1800.0, 7200.0))
#: sigma_max / expected maximum error tried: the thesis's range 5-15 % (recommendation 10 %).
SIGMA_MAX_RATIOS = (0.05, 0.10, 0.15)
#: Slow-error filter grid (as the calibrated TALC's).
BIAS_TAU_GRID_S = (1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 86400.0)
NOISE_RATIO_GRID = (0.0, 0.3, 1.0, 3.0)
FOLD_STARTS = (0.6, 0.7, 0.8)
#: Calibration points: one per 5-min grid sample of the calibration rows (charged in Q_prod).
CALIBRATION_STEP_S = 300.0


@dataclass(frozen=True)
class AgpSchedule:
    """When the calibrated AGP probes after calibration (one probing measures every channel)."""

    control_interval_s: float = 7200.0        # issue 10: one probing every 2 h
    probe_duration_s: float = 95.0            # charged in Q_prod; intervals count from the cycle end
    min_sigma_probe_interval_s: float = 600.0  # sigma_max probes at most one per 10 min
    control_tolerance_um: float = 1.0         # e_tol: a control measurement further off re-optimises
    noise_guard_factor: float = 1.5           # as AgpConfig.noise_guard_factor

    def __post_init__(self) -> None:
        for name in ("control_interval_s", "probe_duration_s", "min_sigma_probe_interval_s",
                     "control_tolerance_um", "noise_guard_factor"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise FlThermalError(f"{name}: {v!r} must be a finite number > 0")


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

    @property
    def measured_rows(self) -> list[int]:
        """The last calibration probing, then every probe row: where the displacement is known."""
        return [self.last_calibration_row] + list(self.probe_rows)

    @property
    def sigma_probes(self) -> int:
        return sum(r == "sigma_max" for r in self.probe_reasons)


def agp_input_sensors(temperatures: np.ndarray, seed: int = 0, time_s: np.ndarray | None = None,
                      displacements: np.ndarray | None = None) -> list[str]:
    """One medoid per unique sensor group (WCSS elbow, thesis §5.1) of the given rows, plus (given
    ``time_s`` and ``displacements`` of the same rows) the :func:`fast_sensor` if no medoid is
    it. A medoid stands for its group's slow level and averages the spindle-near sensor's fast
    swings away, which lead the displacement's. Walk-forward inside FL_THERMAL's training rows
    (60/70/80 % folds, selected GP settings): mean MAE 2.47 um with the medoids alone, 1.59 with
    the fast sensor added."""
    groups = sensor_groups(temperatures, seed=seed)
    sensors = sensor_medoids(temperatures, groups.n_groups, SENSORS, seed=seed)
    if time_s is not None and displacements is not None:
        fast = fast_sensor(time_s, temperatures, displacements, SENSORS)
        if fast not in sensors:
            sensors.append(fast)
    return sensors


def agp_features(data: FlThermalData, sensors: Sequence[str], taus_s: Sequence[float]) -> np.ndarray:
    """GP inputs for every row, causal: medoid temperatures (change from row 0) and low-pass copies."""
    unknown = [s for s in sensors if s not in SENSORS]
    if unknown or not sensors:
        raise FlThermalError(f"sensors: {list(sensors)!r} must be a non-empty subset of {list(SENSORS)}")
    idx = [SENSORS.index(s) for s in sensors]
    return lagged_features(data.time_s, data.temperatures[:, idx], list(taus_s))


def calibration_rows(time_s: np.ndarray, n_calibration: int) -> np.ndarray:
    """Rows of the 5-min grid samples before ``n_calibration`` (the charged calibration probings)."""
    dt = float(np.median(np.diff(time_s)))
    step = max(1, int(round(CALIBRATION_STEP_S / dt)))
    return np.arange(0, n_calibration, step)


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
    with threadpool_limits(1):
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
        raise FlThermalError(f"start/stop: {start}..{stop} is not a range of 1..{n} rows")
    if not (math.isfinite(sigma_max_um) and sigma_max_um > 0):
        raise FlThermalError(f"sigma_max_um: {sigma_max_um!r} must be a finite number > 0")
    if len(gps) != m or cal_rows.size < 2 or int(cal_rows.max()) >= start:
        raise FlThermalError(f"gps/cal_rows: {len(gps)} GPs for {m} channels, calibration rows must lie before "
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
    with threadpool_limits(1):
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
            if not np.all(np.isfinite(Y[k])):
                raise FlThermalError(f"displacement: row {k} is {Y[k].tolist()!r} at a probing instant")
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
                         int(cal_rows[-1]))


def best_filter(time_s, y, trajectories: Sequence[tuple[int, int, AgpTrajectory]], channel_index: int,
                tau_grid=BIAS_TAU_GRID_S, ratio_grid=NOISE_RATIO_GRID, hold_rates: Sequence[float] | None = None
                ) -> tuple[SlowErrorFilter, float, list[float]]:
    """The (tau, r) with the lowest mean MAE over the replays (start, stop, trajectory) of one
    channel; with ``hold_rates`` (one per replay) the compensation is scored after the
    :func:`uncertainty_weighted_hold` with that replay's rate."""
    j = channel_index
    rates = [math.inf] * len(trajectories) if hold_rates is None else [float(q) for q in hold_rates]
    if len(rates) != len(trajectories):
        raise FlThermalError(f"hold_rates: {len(rates)} given for {len(trajectories)} replays")
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
class CalibratedAgp:
    compensation: dict[str, np.ndarray]
    gp_mean: dict[str, np.ndarray]
    trajectory: AgpTrajectory
    filters: dict[str, SlowErrorFilter]
    hold_rates: dict[str, float]
    sensors: list[str]
    feature_taus_s: tuple[float, ...]
    sigma_max_ratio: float
    calibration_probings: int
    schedule: AgpSchedule
    walk_forward: dict[str, Any] = field(default_factory=dict)


def _calibrated_trajectory(data: FlThermalData, Y: np.ndarray, n_cal: int, stop: int, taus, ratios,
                           schedule: AgpSchedule, seed: int, progress) -> dict[tuple, tuple[AgpTrajectory, list[str]]]:
    """Trajectories of every (taus, ratio) for calibration rows 0..n_cal-1, replay n_cal..stop-1."""
    sensors = agp_input_sensors(data.temperatures[:n_cal], seed=seed, time_s=data.time_s[:n_cal],
                                 displacements=Y[:n_cal])
    cal = calibration_rows(data.time_s, n_cal)
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


def run_calibrated_agp(data: FlThermalData, splits: Splits, *, schedule: AgpSchedule = AgpSchedule(),
                       feature_tau_sets: Sequence[Sequence[float]] = FEATURE_TAU_SETS,
                       sigma_max_ratios: Sequence[float] = SIGMA_MAX_RATIOS, fold_starts: Sequence[float] = FOLD_STARTS,
                       tau_grid=BIAS_TAU_GRID_S, ratio_grid=NOISE_RATIO_GRID, hold: bool = True,
                       target_um: float = 1.0,
                       seed: int = 0, progress: Callable[[], Any] | None = None) -> CalibratedAgp:
    """Walk-forward selection inside rows < n_train, then calibration on all training rows and
    the replay of the rows after (module docstring)."""
    n = splits.n_train
    if not feature_tau_sets or not sigma_max_ratios:
        raise FlThermalError("feature_tau_sets / sigma_max_ratios: need at least one candidate each")
    bad = [r for r in sigma_max_ratios if not (isinstance(r, (int, float)) and 0 < r < 1)]
    if bad:
        raise FlThermalError(f"sigma_max_ratios: {bad!r} must lie in (0, 1)")
    Y = np.column_stack([data.displacement_um[ch] for ch in CHANNELS])
    folds = []
    for k in walk_forward_fold_rows(fold_starts, n):
        folds.append((k, _calibrated_trajectory(data, Y, k, n, feature_tau_sets, sigma_max_ratios, schedule, seed,
                                                progress)))
    scores: dict[str, Any] = {}
    candidates = []
    # each fold's hold rate per channel, from that fold's calibration rows (same for every key)
    fold_rates = {ch: [measured_hold_rate(data.time_s, Y[:, j], k) for k, _ in folds] if hold else None
                  for j, ch in enumerate(CHANNELS)}
    for key in folds[0][1]:
        per_ch, filters = {}, {}
        for j, ch in enumerate(CHANNELS):
            filters[ch], per_ch[ch], _ = best_filter(data.time_s, Y[:, j], [(k, n, fl[key][0]) for k, fl in folds],
                                                     j, tau_grid, ratio_grid, fold_rates[ch])
        probings = float(np.mean([len(fl[key][0].probe_rows) for _, fl in folds]))
        label = f"taus={'+'.join(f'{t / 3600:g}h' for t in key[0]) or 'none'},sigma_ratio={key[1]:g}"
        scores[label] = {"mae_um": {ch: round(v, 3) for ch, v in per_ch.items()},
                         "mean_probings": round(probings, 1)}
        candidates.append((key, per_ch, probings, filters))
    meeting = [c for c in candidates if max(c[1].values()) <= target_um]
    if meeting:
        key, _, _, filters = min(meeting, key=lambda c: (c[2], float(np.mean(list(c[1].values())))))
    else:
        key, _, _, filters = min(candidates, key=lambda c: float(np.mean(list(c[1].values()))))
    traj, sensors = _calibrated_trajectory(data, Y, n, len(data), [key[0]], [key[1]], schedule, seed, progress)[key]
    comp, gp_mean, hold_rates = {}, {}, {}
    for j, ch in enumerate(CHANNELS):
        hold_rates[ch] = measured_hold_rate(data.time_s, Y[:, j], n) if hold else math.inf
        c = slow_error_compensation(data.time_s, Y[:, j], traj.mean[:, j], traj.probe_rows,
                                    traj.post_probe_mean[:, j], n, len(data), filters[ch])
        comp[ch] = uncertainty_weighted_hold(data.time_s, Y[:, j], c, traj.std[:, j], traj.measured_rows, n,
                                             len(data), hold_rates[ch])
        gp_mean[ch] = traj.mean[:, j]
    return CalibratedAgp(comp, gp_mean, traj, filters, hold_rates, sensors, key[0], key[1],
                         int(calibration_rows(data.time_s, n).size), schedule,
                         {"scores": scores, "met_target_on_every_channel": bool(meeting)})


def calibrated_agp_figures(data: FlThermalData, splits: Splits, result: CalibratedAgp) -> dict[str, Any]:
    """MAE per channel and split, probings (and how many sigma_max triggered), Q_prod two ways."""
    figures: dict[str, Any] = {}
    tr = result.trajectory
    rows = tr.probe_rows
    first = rows[0] if rows else splits.n
    blind, seen = slice(splits.n_train, min(first, splits.test_end)), slice(min(first, splits.test_end),
                                                                          splits.test_end)
    for j, ch in enumerate(CHANNELS):
        y = data.displacement_um[ch]
        c, f = result.compensation[ch], result.filters[ch]
        # the baseline a dense schedule must beat: hold each measurement until the next one
        hold = uncertainty_weighted_hold(data.time_s, y, c, tr.std[:, j], tr.measured_rows, splits.n_train,
                                         splits.n, 0.0)
        figures[ch] = {"mae_um": round(mae(y[splits.test], c[splits.test]), 3),
                       "mae_validation_um": round(mae(y[splits.validation], c[splits.validation]), 3),
                       # test rows before / from the first probing after calibration (blind / probed)
                       "mae_before_first_probe_um": round(mae(y[blind], c[blind]), 3),
                       "mae_from_first_probe_um": round(mae(y[seen], c[seen]), 3),
                       "gp_mean_mae_um": round(mae(y[splits.test], result.gp_mean[ch][splits.test]), 3),
                       "bias_time_constant_h": round(f.bias_time_constant_s / 3600.0, 3),
                       "noise_ratio": f.noise_ratio,
                       # the uncertainty-weighted hold's measured rate; "inf" = the GP compensation alone
                       "hold_rate_um2_per_h": ("inf" if math.isinf(result.hold_rates[ch])
                                               else round(result.hold_rates[ch], 2)),
                       "hold_last_measurement_mae_um": round(mae(y[splits.test], hold[splits.test]), 3),
                       "hold_last_measurement_mae_validation_um": round(mae(y[splits.validation],
                                                                            hold[splits.validation]), 3)}
    dur = result.schedule.probe_duration_s
    total_s = float(data.time_s[-1] - data.time_s[0])
    after_s = float(data.time_s[-1] - data.time_s[splits.n_train - 1])
    figures["inputs"] = list(result.sensors)
    figures["feature_taus_s"] = list(result.feature_taus_s)
    figures["sigma_max_ratio"] = result.sigma_max_ratio
    figures["sigma_max_um"] = round(tr.sigma_max_um, 3)
    figures["calibration_probings"] = result.calibration_probings
    figures["probing_cycles"] = result.calibration_probings + len(rows)
    figures["probing_cycles_after_calibration"] = len(rows)
    figures["sigma_max_probings"] = tr.sigma_probes
    figures["control_probings"] = len(rows) - tr.sigma_probes
    figures["probing_cycles_test_rows"] = int(sum(splits.n_train <= r < splits.test_end for r in rows))
    figures["probing_cycles_validation_rows"] = int(sum(splits.test_end <= r < splits.n for r in rows))
    figures["sigma_max_probings_test_rows"] = int(sum(splits.n_train <= r < splits.test_end and why == "sigma_max"
                                                      for r, why in zip(rows, tr.probe_reasons)))
    figures["parameter_updates"] = tr.refits_optimised
    figures["first_probe_after_calibration_h"] = (round(float(data.time_s[rows[0]] / 3600.0), 2) if rows else None)
    figures["q_prod_pct"] = round(q_prod_pct(result.calibration_probings + len(rows), total_s, dur), 2)
    figures["q_prod_after_calibration_pct"] = round(q_prod_pct(len(rows), after_s, dur), 2)
    figures["walk_forward"] = result.walk_forward
    return figures


def plot_agp_uncertainty(data: FlThermalData, splits: Splits, result: CalibratedAgp, path) -> None:
    """PNG: per channel, measured vs compensation (top) and the GP's predictive std against the
    effective threshold's floor sigma_max (bottom), probings as ticks (control / sigma_max)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    tr = result.trajectory
    rows = slice(splits.n_train, splits.n)
    th = data.time_s[rows] / 3600.0
    fig, axes = plt.subplots(len(CHANNELS), 2, figsize=(15, 2.8 * len(CHANNELS)), sharex=True)
    for j, ch in enumerate(CHANNELS):
        y = data.displacement_um[ch][rows]
        ax, ax_s = axes[j]
        ax.plot(th, y, color="k", lw=1.4, label="measured")
        ax.plot(th, result.compensation[ch][rows], lw=1, label="agp_calibrated compensation")
        ax.set_ylabel(f"{ch} (um)")
        ax_s.plot(th, tr.std[rows, j], lw=1, color="tab:purple", label="GP predictive std")
        ax_s.axhline(tr.sigma_max_um, color="tab:red", ls="--", lw=1, label="sigma_max")
        for r, why in zip(tr.probe_rows, tr.probe_reasons):
            for a in (ax, ax_s):
                a.axvline(data.time_s[r] / 3600.0, color="tab:red" if why == "sigma_max" else "tab:green",
                          lw=0.4, alpha=0.5)
        for a in (ax, ax_s):
            a.axvline(data.time_s[splits.test_end] / 3600.0, color="0.5", ls=":", lw=1)
        ax_s.set_ylabel("std (um)")
    axes[0][0].legend(fontsize=7)
    axes[0][1].legend(fontsize=7)
    axes[0][0].set_title("after calibration: red lines = sigma_max probings, green = 2-h control probings; "
                         "dotted = test | validation", fontsize=8)
    axes[-1][0].set_xlabel("time since start (h)")
    axes[-1][1].set_xlabel("time since start (h)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def run_agp_calibrated_variant(data: FlThermalData, splits: Splits, *, show_progress: bool = True,
                               out_dir=None, **selection) -> tuple[dict[str, Any], dict[str, np.ndarray], list[int]]:
    """Bench row ``agp_calibrated``: figures, compensation per channel and probe rows (and, with
    ``out_dir``, ``fl_thermal_agp_calibrated.png``: the GP std against sigma_max)."""
    import time
    from tqdm import tqdm
    n_taus = len(selection.get("feature_tau_sets", FEATURE_TAU_SETS))
    n_ratios = len(selection.get("sigma_max_ratios", SIGMA_MAX_RATIOS))
    n_folds = len(selection.get("fold_starts", FOLD_STARTS))
    t0 = time.perf_counter()
    with tqdm(total=n_folds * n_taus * n_ratios + 1, desc="adaptive AGP (calibrated on the training rows)",
              unit="replay", disable=not show_progress, leave=False) as bar:
        res = run_calibrated_agp(data, splits, progress=bar.update, **selection)
    figures = calibrated_agp_figures(data, splits, res)
    figures["run_s"] = round(time.perf_counter() - t0, 1)
    if out_dir is not None:
        import pathlib
        png = pathlib.Path(out_dir) / "fl_thermal_agp_calibrated.png"
        png.parent.mkdir(parents=True, exist_ok=True)
        plot_agp_uncertainty(data, splits, res, png)
        figures["plot"] = str(png)
    return figures, res.compensation, list(res.trajectory.probe_rows)
