"""Adaptive Gaussian process (AGP) thermal-error model of the Swiss-type-lathe thesis.

Spec: ``shared/spec/agp-swiss-lathe-thesis.md`` §2-5, §11. Pieces:

* :class:`ArdGaussianProcess` - ARD-RBF plus white-noise GP (scikit-learn
  ``GaussianProcessRegressor``, L-BFGS-B on the log marginal likelihood, Eqs 4.8-4.19) on
  standardised inputs and standardised outputs. The predictive std *includes* the noise
  (K** carries the delta term, Eq. 4.17), as in the thesis. Refits warm-start from the previous
  hyperparameters (the length scales drift slowly as data accumulate, thesis Figs 4.4-4.6).
* :func:`sensor_groups` / :func:`calibration_points_needed` - unique input groups by k-means on
  the sensors' standardised time series with a WCSS elbow; N_min = 10 x groups (§3.1).
* :class:`AdaptiveGaussianProcess` (kind ``"agp"``) - the AGP of thesis Fig. 5.13 behind the shared
  :class:`~talc_model.adaptive_model.AdaptiveModel` protocol: a calibration phase that compensates
  with the measured (TLS) error itself and probes every part cycle until N_min points *and* the
  minimum calibration time are reached; then a prediction phase that probes only when the
  predictive std exceeds sigma_max (recalibration: refit on all data, hyperparameters
  re-optimised) or when an optional control measurement is due (refit only if
  |e - mu| > e_tol). With ``recalibration: false`` (kind ``"gp_static"``) it is the plain GP
  without recalibration the thesis compares against (Table 6.1).
* :class:`OffsetModel` - multi-TCP "GPR-offset models" (§5.2): Delta_k = e_k - e_base predicted
  from tool-position temperatures, trained offline; e_k = AGP(base) + Delta_k (our sign
  convention, '+' as in thesis Ch. 7). They are not recalibrated in production (thesis Ch. 8).
  The std of a tool component is sqrt(std_base^2 + std_offset^2) (independence assumed; the
  thesis does not say how to combine them).

Choices for the thesis's gaps (§9), each a config key: inputs are the temperatures as given
(absolute), standardised at every fit with a scale floor ``min_input_scale``; length-scale
bounds [0.01, 100] in standardised units - the upper bound is lower than the 1e4 of the peer
implementation on purpose: an input that hardly moved during training (cutting oil held
constant) must not be switched off for good by ARD, else a later step in it leaves the std low
while the error runs away; with the bound, a move of many training spreads makes the state
"unseen" and the std rise, which is what triggers recalibration (thesis §5.2.3); ``noise_guard_factor``: the effective threshold is
max(sigma_max, factor x fitted noise std) so that recalibration cannot fire every cycle (gap 2);
sensors reading NaN are held at their last valid value and reported as excluded; TLS smoothing
by an optional EWMA (``tls_ewma_alpha``, 1 = none); a floor on the GP's prior std
(``min_signal_std_ratio`` x the expected maximum error, see :class:`ArdGaussianProcess`) so that
an unseen state can always raise the std above sigma_max; before any measurement the prediction is 0
(errors are relative to the start, §5.3).

No rclpy here.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping, Sequence

import numpy as np
from sklearn.cluster import KMeans
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from threadpoolctl import threadpool_limits

from talc_model.adaptive_model import (PHASE_CALIBRATION, PHASE_COMPENSATION, ModelStatusData,
                                       register_model)


class AgpConfigError(ValueError):
    """Bad AGP configuration or state; the message names the key and value."""


# ---------------------------------------------------------------------------------------
# The GP regressor

def _kernel(n_inputs: int, length_scale_bounds: tuple[float, float],
            noise_bounds: tuple[float, float], signal_var_lower: float = 1e-3):
    lower = min(max(float(signal_var_lower), 1e-3), 1.0)
    return (ConstantKernel(1.0, (lower, 1e3)) * RBF(np.ones(n_inputs), length_scale_bounds)
            + WhiteKernel(1e-2, noise_bounds))


class ArdGaussianProcess:
    """ARD-RBF + white-noise GP regression on standardised inputs and outputs.

    ``fit`` maximises the log marginal likelihood with L-BFGS-B (``n_restarts`` extra random
    starts); with ``warm_start`` the optimiser starts from the previous fit's hyperparameters.

    ``min_signal_std`` (output units, 0 = off) is a floor on the prior std of the latent
    function: outputs are scaled by max(std(y), min_signal_std) and the signal variance is
    bounded below accordingly. It encodes the prior belief that a state unlike all training
    states may carry an error of that size; without it a calibration that saw little error
    variation yields a prior std below sigma_max, and an unseen state could never trigger a
    recalibration (observed on the twin's lathe-random-speed, whose first hours are calm).

    ``max_optimize_points`` (0 = off): above this many points the hyperparameters are optimised
    on an even thinning of the data and the posterior is then computed on all of it - the
    gradient of scikit-learn's likelihood costs O(N^2 x hyperparameters) memory and O(N^3) time
    per evaluation, and the optimum hardly moves with N.
    """

    def __init__(self, *, length_scale_bounds: tuple[float, float] = (1e-2, 1e2),
                 noise_bounds: tuple[float, float] = (1e-6, 1.0), n_restarts: int = 0,
                 min_input_scale: float = 0.05, min_signal_std: float = 0.0,
                 max_optimize_points: int = 0, seed: int = 0):
        self.length_scale_bounds = tuple(float(v) for v in length_scale_bounds)
        self.noise_bounds = tuple(float(v) for v in noise_bounds)
        self.n_restarts = int(n_restarts)
        self.min_input_scale = float(min_input_scale)
        self.min_signal_std = float(min_signal_std)
        self.max_optimize_points = int(max_optimize_points)
        self.seed = int(seed)
        self.gpr: GaussianProcessRegressor | None = None
        self.x_mean: np.ndarray | None = None
        self.x_scale: np.ndarray | None = None
        self.y_mean = 0.0
        self.y_scale = 1.0
        self.optimizer_warnings = 0

    @property
    def fitted(self) -> bool:
        return self.gpr is not None

    def _scale(self, x: np.ndarray) -> np.ndarray:
        return (x - self.x_mean) / self.x_scale

    def fit(self, x, y, *, warm_start: bool = True, optimize: bool = True) -> "ArdGaussianProcess":
        """Fit on (x, y). ``optimize=False`` keeps the hyperparameters and scalings of the last
        fit and only conditions on the data (cheap update after a control measurement)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float).ravel()
        if x.ndim != 2 or x.shape[0] != y.shape[0]:
            raise AgpConfigError(f"GP fit: x has shape {x.shape}, y has {y.shape[0]} values")
        if x.shape[0] < 2:
            raise AgpConfigError(f"GP fit: needs >= 2 training points, got {x.shape[0]}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise AgpConfigError("GP fit: training inputs/outputs contain NaN or inf")
        previous = self.gpr.kernel_ if (self.gpr is not None
                                        and self.gpr.kernel_.k1.k2.length_scale.size == x.shape[1]) else None
        if optimize or previous is None:
            self.x_mean = x.mean(axis=0)
            self.x_scale = np.maximum(x.std(axis=0), self.min_input_scale)
            self.y_mean = float(y.mean())
            self.y_scale = max(float(y.std()), self.min_signal_std, 1e-9)
        lower = (self.min_signal_std / self.y_scale) ** 2 if self.min_signal_std > 0 else 1e-3
        kernel = _kernel(x.shape[1], self.length_scale_bounds, self.noise_bounds, lower)
        if previous is not None and (warm_start or not optimize):
            theta = previous.theta.copy()
            b = kernel.bounds
            kernel.theta = np.clip(theta, b[:, 0], b[:, 1])
        xs, ys = self._scale(x), (y - self.y_mean) / self.y_scale
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            if optimize and self.max_optimize_points and x.shape[0] > self.max_optimize_points:
                # hyperparameters from an even thinning of the history (the likelihood surface
                # is flat in N: its optimum moves little), then the exact posterior on all points
                sub = np.unique(np.linspace(0, x.shape[0] - 1, self.max_optimize_points).round().astype(int))
                opt = GaussianProcessRegressor(kernel=kernel, normalize_y=False, optimizer="fmin_l_bfgs_b",
                                               n_restarts_optimizer=self.n_restarts, random_state=self.seed)
                opt.fit(xs[sub], ys[sub])
                kernel, optimize = opt.kernel_, False
            gpr = GaussianProcessRegressor(kernel=kernel, normalize_y=False,
                                           optimizer="fmin_l_bfgs_b" if optimize else None,
                                           n_restarts_optimizer=self.n_restarts if optimize else 0,
                                           random_state=self.seed)
            gpr.fit(xs, ys)
        self.optimizer_warnings += sum(issubclass(w.category, ConvergenceWarning) for w in caught)
        self.gpr = gpr
        return self

    def predict(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Mean and predictive std (including noise, thesis Eq. 4.17) in output units."""
        if self.gpr is None:
            raise AgpConfigError("GP is not fitted")
        x = np.atleast_2d(np.asarray(x, dtype=float))
        mean, std = self.gpr.predict(self._scale(x), return_std=True)
        return (np.asarray(mean, dtype=float) * self.y_scale + self.y_mean,
                np.asarray(std, dtype=float) * self.y_scale)

    @property
    def noise_std(self) -> float:
        """Fitted white-noise std in output units."""
        if self.gpr is None:
            return math.nan
        return float(math.sqrt(self.gpr.kernel_.k2.noise_level) * self.y_scale)

    @property
    def prior_std(self) -> float:
        """Predictive std far from all training data (signal and noise) in output units."""
        if self.gpr is None:
            return math.nan
        k = self.gpr.kernel_
        return float(math.sqrt(k.k1.k1.constant_value + k.k2.noise_level) * self.y_scale)

    @property
    def length_scales(self) -> np.ndarray:
        """ARD length scales in standardised input units (relevance = 1 / length scale)."""
        if self.gpr is None:
            raise AgpConfigError("GP is not fitted")
        return np.atleast_1d(np.asarray(self.gpr.kernel_.k1.k2.length_scale, dtype=float))

    @property
    def log_marginal_likelihood(self) -> float:
        return float(self.gpr.log_marginal_likelihood_value_) if self.gpr is not None else math.nan

    def to_state(self) -> dict:
        base = {"length_scale_bounds": list(self.length_scale_bounds), "noise_bounds": list(self.noise_bounds),
                "n_restarts": self.n_restarts, "min_input_scale": self.min_input_scale,
                "min_signal_std": self.min_signal_std, "max_optimize_points": self.max_optimize_points,
                "seed": self.seed}
        if self.gpr is None:
            return {"fitted": False, **base}
        x_train = self.gpr.X_train_ * self.x_scale + self.x_mean
        y_train = np.asarray(self.gpr.y_train_).ravel() * self.y_scale + self.y_mean
        return {"fitted": True, **base, "theta": self.gpr.kernel_.theta.tolist(),
                "x_mean": self.x_mean.tolist(), "x_scale": self.x_scale.tolist(),
                "y_mean": self.y_mean, "y_scale": self.y_scale,
                "x_train": x_train.tolist(), "y_train": y_train.tolist()}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "ArdGaussianProcess":
        try:
            gp = cls(length_scale_bounds=tuple(state["length_scale_bounds"]),
                     noise_bounds=tuple(state["noise_bounds"]), n_restarts=int(state["n_restarts"]),
                     min_input_scale=float(state["min_input_scale"]),
                     min_signal_std=float(state["min_signal_std"]),
                     max_optimize_points=int(state.get("max_optimize_points", 0)), seed=int(state["seed"]))
            if not state.get("fitted", False):
                return gp
            x = np.asarray(state["x_train"], dtype=float)
            y = np.asarray(state["y_train"], dtype=float)
            gp.x_mean = np.asarray(state["x_mean"], dtype=float)
            gp.x_scale = np.asarray(state["x_scale"], dtype=float)
            gp.y_mean, gp.y_scale = float(state["y_mean"]), float(state["y_scale"])
            kernel = _kernel(x.shape[1], gp.length_scale_bounds, gp.noise_bounds, 1e-3)
            kernel.theta = np.asarray(state["theta"], dtype=float)
        except KeyError as exc:
            raise AgpConfigError(f"GP state: missing key {exc}") from None
        gp.gpr = GaussianProcessRegressor(kernel=kernel, normalize_y=False, optimizer=None)
        gp.gpr.fit(gp._scale(x), (y - gp.y_mean) / gp.y_scale)
        return gp


# ---------------------------------------------------------------------------------------
# Calibration length from unique sensor groups

@dataclass
class SensorGroups:
    n_groups: int
    labels: list[int]
    wcss: list[float]          # within-cluster sum of squares for k = 0 (about zero), 1, 2, ...


def sensor_groups(series, *, max_groups: int = 10, seed: int = 0) -> SensorGroups:
    """Unique input groups: k-means over the sensors (as samples) of their standardised time
    series, number of groups from the WCSS elbow (thesis §5.1, Fig. 5.2).

    Each sensor's series is z-scored, so mutually correlated sensors lie close together. The
    elbow is the point of the WCSS curve farthest from the chord between k = 0 (all series
    about the zero vector, WCSS = total sum of squares) and k = k_max; the k = 0 anchor lets
    a single group of correlated sensors show its elbow at k = 1 (our choice; the thesis reads
    the elbow by eye). Constant sensors carry no information and form no group of their own.
    """
    s = np.asarray(series, dtype=float)
    if s.ndim != 2:
        raise AgpConfigError(f"sensor series: expected (time, sensors), got shape {s.shape}")
    s = s[np.all(np.isfinite(s), axis=1)]
    if s.shape[0] < 3:
        raise AgpConfigError(f"sensor series: needs >= 3 complete rows, got {s.shape[0]}")
    std = s.std(axis=0)
    moving = std > 1e-9
    labels = [-1] * s.shape[1]
    if not moving.any():
        return SensorGroups(1, [0] * s.shape[1], [0.0])
    z = ((s[:, moving] - s[:, moving].mean(axis=0)) / std[moving]).T   # sensors x time
    p = z.shape[0]
    k_max = min(max_groups, p)
    wcss = [float(np.sum(z ** 2))]
    fits = {}
    for k in range(1, k_max + 1):
        with threadpool_limits(1):   # tiny problem: OpenMP threads only contend on a shared machine
            km = KMeans(n_clusters=k, n_init=10, random_state=seed).fit(z)
        fits[k] = km
        wcss.append(float(km.inertia_))
    ks = np.arange(0, k_max + 1, dtype=float)
    w = np.asarray(wcss)
    if k_max == 1:
        n_groups = 1
    else:
        # distance of (k, W_k) from the chord (0, W_0)-(k_max, W_kmax), both axes normalised
        kx = ks / k_max
        wy = (w - w[-1]) / max(w[0] - w[-1], 1e-12)
        dist = np.abs((1 - kx) - wy) / math.sqrt(2.0)   # chord: wy = 1 - kx
        n_groups = int(np.argmax(dist[1:]) + 1)
    moving_labels = fits[n_groups].labels_.tolist()
    it = iter(moving_labels)
    labels = [int(next(it)) if m else -1 for m in moving]
    return SensorGroups(n_groups, labels, wcss)


def calibration_points_needed(series, *, points_per_group: int = 10, max_groups: int = 10,
                              seed: int = 0) -> tuple[int, SensorGroups]:
    """N_min = points_per_group x unique sensor groups (Loeppky's 10 x rule, thesis §5.1)."""
    groups = sensor_groups(series, max_groups=max_groups, seed=seed)
    return points_per_group * groups.n_groups, groups


# ---------------------------------------------------------------------------------------
# Multi-TCP offset models

class OffsetModel:
    """GPR-offset model of one tool position: Delta_k = e_k - e_base from tool temperatures."""

    def __init__(self, component: str, base: str, sensors: Sequence[str], gp: ArdGaussianProcess | None = None):
        self.component = component
        self.base = base
        self.sensors = list(sensors)
        if not self.sensors:
            raise AgpConfigError(f"offset model {component!r}: 'sensors' is empty")
        self.gp = gp or ArdGaussianProcess()

    def fit(self, temperatures: Mapping[str, Sequence[float]], error_k, error_base,
            max_points: int = 1500) -> "OffsetModel":
        """Train offline on a multi-TCP training test (arrays over time). Rows with NaN are
        dropped; long tests are thinned evenly to ``max_points`` (O(N^3) fit)."""
        missing = [s for s in self.sensors if s not in temperatures]
        if missing:
            raise AgpConfigError(f"offset model {self.component!r}: sensors {missing} not in the training data")
        x = np.column_stack([np.asarray(temperatures[s], dtype=float) for s in self.sensors])
        d = np.asarray(error_k, dtype=float) - np.asarray(error_base, dtype=float)
        ok = np.all(np.isfinite(x), axis=1) & np.isfinite(d)
        x, d = x[ok], d[ok]
        if x.shape[0] > max_points:
            keep = np.linspace(0, x.shape[0] - 1, max_points).round().astype(int)
            x, d = x[keep], d[keep]
        self.gp.fit(x, d, warm_start=False)
        return self

    def predict(self, temperatures: Mapping[str, float]) -> tuple[float, float]:
        x = np.array([[float(temperatures.get(s, math.nan)) for s in self.sensors]])
        if not np.all(np.isfinite(x)) or not self.gp.fitted:
            return math.nan, math.nan
        m, s = self.gp.predict(x)
        return float(m[0]), float(s[0])

    def to_state(self) -> dict:
        return {"component": self.component, "base": self.base, "sensors": self.sensors,
                "gp": self.gp.to_state()}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "OffsetModel":
        try:
            return cls(state["component"], state["base"], state["sensors"],
                       ArdGaussianProcess.from_state(state["gp"]))
        except KeyError as exc:
            raise AgpConfigError(f"offset model state: missing key {exc}") from None


# ---------------------------------------------------------------------------------------
# The adaptive model

@dataclass
class AgpConfig:
    """Configuration of :class:`AdaptiveGaussianProcess` (every key of the mapping)."""

    components: list[str] = field(default_factory=lambda: ["GB_X"])   # measured (TLS) components
    sensors: list[str] | None = None          # GP input sensors; None = all seen at the first update
    machine_inputs: list[str] = field(default_factory=list)   # machine_state keys used as inputs too
    sigma_max_um: float | None = None         # absolute threshold; default ratio x max expected error
    sigma_max_ratio: float = 0.10             # thesis recommendation 10 % (5-15 %)
    max_expected_error_um: float = 30.0       # "several tens of micrometres"
    noise_guard_factor: float = 1.5
    recalibration: bool = True                # False: plain GP without recalibration
    calibration_probe_interval_s: float = 360.0   # one probe per part cycle (6 min test piece)
    min_calibration_s: float = 4 * 3600.0     # walk-forward result of thesis §5.2.2
    max_calibration_s: float = 20 * 3600.0
    points_per_group: int = 10
    max_groups: int = 10
    min_probe_interval_s: float = 360.0       # recalibration probes at most once per part cycle
    control_interval_s: float = 0.0           # optional control measurements (0 = off)
    control_tolerance_um: float = 2.0         # e_tol
    tls_ewma_alpha: float = 1.0               # TLS smoothing (1 = none)
    probe_duration_s: float = 95.0
    length_scale_bounds: tuple[float, float] = (1e-2, 1e2)
    noise_bounds: tuple[float, float] = (1e-6, 1.0)
    n_restarts: int = 0
    min_input_scale: float = 0.05
    min_signal_std_ratio: float = 0.25       # prior std floor = ratio x max expected error (0 = off)
    max_training_points: int = 2000           # refits past this use an even thinning of the history
    max_optimize_points: int = 600            # hyperparameters from at most this many points (0 = all)
    max_history_rows: int = 20000             # input history kept for the k-means grouping
    seed: int = 0
    offset_models: list[dict] = field(default_factory=list)   # OffsetModel.to_state() dicts

    @classmethod
    def from_mapping(cls, config: Mapping[str, Any]) -> "AgpConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(config) - known)
        if unknown:
            raise AgpConfigError(f"agp config: unknown key(s) {unknown} (known: {sorted(known)})")
        cfg = cls(**{k: v for k, v in config.items()})
        cfg.validate()
        return cfg

    def validate(self) -> None:
        if not self.components or not all(isinstance(c, str) for c in self.components):
            raise AgpConfigError(f"agp config: 'components' must be a non-empty list of names, got {self.components!r}")
        positive = ("sigma_max_ratio", "max_expected_error_um", "calibration_probe_interval_s",
                    "probe_duration_s", "min_input_scale", "noise_guard_factor")
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise AgpConfigError(f"agp config: '{name}' must be a positive number, got {v!r}")
        for name in ("min_signal_std_ratio", "min_calibration_s", "max_calibration_s", "min_probe_interval_s", "control_interval_s",
                     "control_tolerance_um"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise AgpConfigError(f"agp config: '{name}' must be a number >= 0, got {v!r}")
        if self.sigma_max_um is not None and not (math.isfinite(self.sigma_max_um) and self.sigma_max_um > 0):
            raise AgpConfigError(f"agp config: 'sigma_max_um' must be positive, got {self.sigma_max_um!r}")
        if not 0 < self.tls_ewma_alpha <= 1:
            raise AgpConfigError(f"agp config: 'tls_ewma_alpha' must be in (0, 1], got {self.tls_ewma_alpha!r}")
        if int(self.max_optimize_points) < 0:
            raise AgpConfigError(f"agp config: 'max_optimize_points' must be >= 0, got {self.max_optimize_points!r}")
        if int(self.max_training_points) < 10:
            raise AgpConfigError(f"agp config: 'max_training_points' must be >= 10, got {self.max_training_points!r}")
        if int(self.points_per_group) < 1 or int(self.max_groups) < 1:
            raise AgpConfigError(f"agp config: 'points_per_group' and 'max_groups' must be >= 1, got "
                                 f"{self.points_per_group!r}, {self.max_groups!r}")

    @property
    def sigma_max(self) -> float:
        return float(self.sigma_max_um) if self.sigma_max_um is not None else \
            self.sigma_max_ratio * self.max_expected_error_um


@register_model("agp")
class AdaptiveGaussianProcess:
    """The AGP behind the shared AdaptiveModel protocol (see the module docstring)."""

    kind = "agp"

    def __init__(self, config: Mapping[str, Any] | AgpConfig | None = None):
        self.config = config if isinstance(config, AgpConfig) else AgpConfig.from_mapping(config or {})
        cfg = self.config
        self.offset_models = [OffsetModel.from_state(s) for s in cfg.offset_models]
        for om in self.offset_models:
            if om.base not in cfg.components:
                raise AgpConfigError(f"agp config: offset model {om.component!r} has base {om.base!r}, "
                                     f"not one of components {cfg.components}")
        self.component_names = list(cfg.components) + [om.component for om in self.offset_models]
        self.gps = {c: self._new_gp() for c in cfg.components}
        self.phase = PHASE_CALIBRATION
        self.input_names: list[str] | None = (list(cfg.sensors) + list(cfg.machine_inputs)) if cfg.sensors else None
        self.held: dict[str, float] = {}
        self.excluded: list[str] = []
        self.current_x: np.ndarray | None = None
        self.current_temperatures: dict[str, float] = {}
        self.history: list[list[float]] = []       # input rows during calibration (k-means)
        self.train_x: list[list[float]] = []
        self.train_y: dict[str, list[float]] = {c: [] for c in cfg.components}
        self.last_total: dict[str, float] = {c: 0.0 for c in cfg.components}
        self.t_start: float | None = None
        self.t_last_probe: float | None = None
        self.probing_cycles = 0
        self.failed_probing_cycles = 0
        self.parameter_updates = 0
        self.recalibration_times: list[float] = []
        self.control_measurements = 0
        self.n_min: int | None = None
        self.n_groups: int | None = None
        self.pending_reason = ""
        self.message = "calibration: compensating with the measured error"
        self._cache_key: int = 0
        self._cache: tuple[int, dict, dict] | None = None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> "AdaptiveGaussianProcess":
        return cls(config)

    def _new_gp(self) -> ArdGaussianProcess:
        c = self.config
        return ArdGaussianProcess(length_scale_bounds=tuple(c.length_scale_bounds),
                                  noise_bounds=tuple(c.noise_bounds), n_restarts=c.n_restarts,
                                  min_input_scale=c.min_input_scale,
                                  min_signal_std=c.min_signal_std_ratio * c.max_expected_error_um,
                                  max_optimize_points=c.max_optimize_points, seed=c.seed)

    # ------------------------------------------------------------------ inputs
    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        if not math.isfinite(t_s):
            raise AgpConfigError(f"update_inputs: t_s {t_s!r} is not a finite time")
        if self.t_start is None:
            self.t_start = float(t_s)
        if self.input_names is None:
            self.input_names = sorted(temperatures) + list(self.config.machine_inputs)
            if not self.input_names:
                raise AgpConfigError("update_inputs: no temperatures and no machine_inputs: the GP has no input")
        values = {**{k: temperatures.get(k, math.nan) for k in temperatures},
                  **{k: machine_state.get(k, math.nan) for k in self.config.machine_inputs}}
        row, excluded = [], []
        for name in self.input_names:
            v = values.get(name, math.nan)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise AgpConfigError(f"update_inputs: input '{name}' = {v!r} is not a number") from None
            if math.isfinite(v):
                self.held[name] = v
            else:
                excluded.append(name)
                v = self.held.get(name, math.nan)
            row.append(v)
        self.excluded = excluded
        self.current_x = np.asarray(row, dtype=float)
        self.current_temperatures = {k: float(v) for k, v in temperatures.items()}
        for k in self.current_temperatures:
            if not math.isfinite(self.current_temperatures[k]) and k in self.held:
                self.current_temperatures[k] = self.held[k]
        if self.phase == PHASE_CALIBRATION and np.all(np.isfinite(self.current_x)):
            self.history.append(row)
            if len(self.history) > self.config.max_history_rows:
                self.history = self.history[::2]   # keep the whole span, thinned
        self._cache_key += 1

    # ------------------------------------------------------------------ prediction
    def _base_prediction(self) -> tuple[dict[str, float], dict[str, float]]:
        if self._cache is not None and self._cache[0] == self._cache_key:
            return self._cache[1], self._cache[2]
        mean, std = {}, {}
        for c in self.config.components:
            gp = self.gps[c]
            if self.phase == PHASE_CALIBRATION or not gp.fitted:
                mean[c], std[c] = self.last_total[c], math.nan
            elif self.current_x is None or not np.all(np.isfinite(self.current_x)):
                mean[c], std[c] = math.nan, math.nan
            else:
                m, s = gp.predict(self.current_x[None, :])
                mean[c], std[c] = float(m[0]), float(s[0])
        self._cache = (self._cache_key, mean, std)
        return mean, std

    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        mean, std = self._base_prediction()
        values, stds = dict(mean), dict(std)
        for om in self.offset_models:
            dm, ds = om.predict(self.current_temperatures)
            values[om.component] = mean[om.base] + dm
            stds[om.component] = math.sqrt(std[om.base] ** 2 + ds ** 2) if math.isfinite(std[om.base]) else math.nan
        return values, stds

    def _prior_std(self) -> dict[str, float]:
        """Std far from all training data, in um, per component."""
        return {c: gp.prior_std for c, gp in self.gps.items() if gp.fitted}

    def effective_sigma_max(self) -> float:
        """sigma_max, raised to noise_guard_factor x the largest fitted noise std (gap 2)."""
        noise = max((gp.noise_std for gp in self.gps.values() if gp.fitted), default=0.0)
        return max(self.config.sigma_max, self.config.noise_guard_factor * noise)

    # ------------------------------------------------------------------ probing
    def _since_probe(self, t_s: float) -> float:
        return math.inf if self.t_last_probe is None else t_s - self.t_last_probe

    def probe_due(self, t_s: float) -> bool:
        cfg = self.config
        if self.phase == PHASE_CALIBRATION:
            due = self._since_probe(t_s) >= cfg.calibration_probe_interval_s
            self.pending_reason = "calibration" if due else ""
            return due
        if cfg.recalibration and self._since_probe(t_s) >= cfg.min_probe_interval_s:
            _, std = self._base_prediction()
            finite = [s for s in std.values() if math.isfinite(s)]
            if finite and max(finite) > self.effective_sigma_max():
                self.pending_reason = "recalibration"
                return True
        if cfg.control_interval_s > 0 and self._since_probe(t_s) >= cfg.control_interval_s:
            self.pending_reason = "control"
            return True
        self.pending_reason = ""
        return False

    def _next_due(self) -> float:
        if self.t_last_probe is None:
            return self.t_start if self.t_start is not None else 0.0
        if self.phase == PHASE_CALIBRATION:
            return self.t_last_probe + self.config.calibration_probe_interval_s
        if self.config.control_interval_s > 0:
            return self.t_last_probe + self.config.control_interval_s
        return math.inf   # only when the uncertainty exceeds sigma_max

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        self.failed_probing_cycles += 1
        self.t_last_probe = float(t_s)
        self.message = f"probing failed at t={t_s:.0f} s: {reason}"

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        cfg = self.config
        if self.current_x is None:
            raise AgpConfigError("add_measurement: no inputs yet (call update_inputs first)")
        totals = {}
        for c in cfg.components:
            v = measured.get(c, math.nan)
            a = applied_compensation.get(c, 0.0)
            a = 0.0 if a is None or not math.isfinite(float(a)) else float(a)
            if v is None or not math.isfinite(float(v)):
                continue
            total = float(v) + a
            if cfg.tls_ewma_alpha < 1.0 and self.train_y[c]:
                total = cfg.tls_ewma_alpha * total + (1 - cfg.tls_ewma_alpha) * self.train_y[c][-1]
            totals[c] = total
        self.t_last_probe = float(t_s)
        reason, self.pending_reason = (self.pending_reason or "unscheduled"), ""
        if len(totals) != len(cfg.components):
            missing = [c for c in cfg.components if c not in totals]
            self.failed_probing_cycles += 1
            self.message = f"measurement at t={t_s:.0f} s lacks component(s) {missing}; not learned from"
            return
        if not np.all(np.isfinite(self.current_x)):
            self.failed_probing_cycles += 1
            self.message = f"measurement at t={t_s:.0f} s: inputs {self.excluded} never valid; not learned from"
            return
        predicted, _ = self._base_prediction()
        self.probing_cycles += 1
        self.train_x.append(self.current_x.tolist())
        for c, v in totals.items():
            self.train_y[c].append(v)
            self.last_total[c] = v
        if self.phase == PHASE_CALIBRATION:
            self._maybe_finish_calibration(t_s)
        elif reason == "recalibration":
            self._refit(optimize=True)
            self.recalibration_times.append(float(t_s))
            self.message = f"recalibrated at t={t_s:.0f} s: std exceeded {self.effective_sigma_max():.2f} um"
        else:
            self.control_measurements += 1
            miss = max(abs(totals[c] - predicted[c]) for c in totals)
            if cfg.recalibration and math.isfinite(miss) and miss > cfg.control_tolerance_um:
                self._refit(optimize=True)
                self.recalibration_times.append(float(t_s))
                self.message = f"recalibrated at t={t_s:.0f} s: control measurement off by {miss:.2f} um"
            elif cfg.recalibration:
                self._refit(optimize=False)   # condition on the new point, hyperparameters kept
                self.message = f"control measurement at t={t_s:.0f} s within {cfg.control_tolerance_um} um"
        self._cache = None

    def training_rows(self) -> np.ndarray:
        """Indices of the history a refit uses: all of it (the thesis never forgets), or, past
        ``max_training_points``, an even thinning over the whole history that always keeps the
        newest point - the exact GP costs O(N^3) per refit (thesis §2.5 proposes Nystrom /
        GPyTorch for machine-life histories; not done here)."""
        n = len(self.train_x)
        cap = int(self.config.max_training_points)
        if n <= cap:
            return np.arange(n)
        return np.unique(np.linspace(0, n - 1, cap).round().astype(int))

    def _refit(self, optimize: bool) -> None:
        rows = self.training_rows()
        x = np.asarray(self.train_x, dtype=float)[rows]
        for c in self.config.components:
            self.gps[c].fit(x, np.asarray(self.train_y[c])[rows], warm_start=True, optimize=optimize)
        if optimize:
            self.parameter_updates += 1

    def _maybe_finish_calibration(self, t_s: float) -> None:
        cfg = self.config
        elapsed = t_s - (self.t_start if self.t_start is not None else t_s)
        n = len(self.train_x)
        # the grouping only matters once the minimum calibration time is over
        if len(self.history) >= 3 and (elapsed >= cfg.min_calibration_s or elapsed >= cfg.max_calibration_s):
            self.n_min, groups = calibration_points_needed(np.asarray(self.history), points_per_group=cfg.points_per_group,
                                                           max_groups=cfg.max_groups, seed=cfg.seed)
            self.n_groups = groups.n_groups
        enough = self.n_min is not None and n >= self.n_min and elapsed >= cfg.min_calibration_s
        timeout = elapsed >= cfg.max_calibration_s and n >= 3
        if not (enough or timeout):
            self.message = (f"calibration: {n} of {self.n_min if self.n_min else '?'} points "
                            f"({self.n_groups or '?'} sensor groups), {elapsed / 3600:.2f} h")
            return
        self._refit(optimize=True)
        self.phase = PHASE_COMPENSATION
        self.history = []
        self.message = (f"calibration finished at t={t_s:.0f} s with {n} points "
                        f"({self.n_groups} sensor groups); predicting")
        prior = min(self._prior_std().values())
        if cfg.recalibration and prior <= self.effective_sigma_max():
            # an unseen state can raise the std at most to the prior std: sigma_max above it
            # means recalibration can never fire (the calibration saw too little variation)
            self.message += (f"; warning: prior std {prior:.2f} um <= sigma_max "
                             f"{self.effective_sigma_max():.2f} um, recalibration cannot trigger")

    # ------------------------------------------------------------------ status and state
    def status(self, t_s: float) -> ModelStatusData:
        elapsed = 0.0 if self.t_start is None else max(t_s - self.t_start, 0.0)
        probing = (self.probing_cycles + self.failed_probing_cycles) * self.config.probe_duration_s
        q = 100.0 if elapsed <= 0 else max(0.0, 100.0 * (1.0 - probing / elapsed))
        _, stds = self.predict(t_s)
        finite = [s for s in stds.values() if math.isfinite(s)]
        return ModelStatusData(phase=self.phase, probing_cycles=self.probing_cycles,
                               failed_probing_cycles=self.failed_probing_cycles, no_good_phases=0,
                               parameter_updates=self.parameter_updates, training_samples=len(self.train_x),
                               q_prod_pct=q, next_probing_due_s=self._next_due(),
                               max_uncertainty=max(finite) if finite else math.nan,
                               excluded_sensor_ids=list(self.excluded), message=self.message)

    def to_state(self) -> dict:
        cfg = asdict(self.config)
        cfg["length_scale_bounds"] = list(cfg["length_scale_bounds"])
        cfg["noise_bounds"] = list(cfg["noise_bounds"])
        return {"kind": self.kind, "config": cfg, "phase": self.phase, "input_names": self.input_names,
                "held": self.held, "excluded": self.excluded,
                "current_x": None if self.current_x is None else self.current_x.tolist(),
                "current_temperatures": self.current_temperatures, "history": self.history,
                "train_x": self.train_x, "train_y": self.train_y, "last_total": self.last_total,
                "t_start": self.t_start, "t_last_probe": self.t_last_probe,
                "probing_cycles": self.probing_cycles, "failed_probing_cycles": self.failed_probing_cycles,
                "parameter_updates": self.parameter_updates, "recalibration_times": self.recalibration_times,
                "control_measurements": self.control_measurements, "n_min": self.n_min,
                "n_groups": self.n_groups, "message": self.message, "pending_reason": self.pending_reason,
                "gps": {c: gp.to_state() for c, gp in self.gps.items()}}

    @classmethod
    def from_state(cls, state: dict) -> "AdaptiveGaussianProcess":
        if state.get("kind") != cls.kind:
            raise AgpConfigError(f"model state: kind {state.get('kind')!r}, expected {cls.kind!r}")
        try:
            model = cls(state["config"])
            for key in ("phase", "input_names", "held", "excluded", "current_temperatures", "history",
                        "train_x", "train_y", "last_total", "t_start", "t_last_probe", "probing_cycles",
                        "failed_probing_cycles", "parameter_updates", "recalibration_times",
                        "control_measurements", "n_min", "n_groups", "message", "pending_reason"):
                setattr(model, key, state[key])
            model.current_x = None if state["current_x"] is None else np.asarray(state["current_x"], dtype=float)
            model.gps = {c: ArdGaussianProcess.from_state(s) for c, s in state["gps"].items()}
        except KeyError as exc:
            raise AgpConfigError(f"model state: missing key {exc}") from None
        if set(model.gps) != set(model.config.components):
            raise AgpConfigError(f"model state: GPs for {sorted(model.gps)}, components {model.config.components}")
        return model


@register_model("gp_static")
class StaticGaussianProcess(AdaptiveGaussianProcess):
    """The plain GP without recalibration (thesis Table 6.1 "without recalibration"): the same
    calibration phase, then predictions from the calibration fit only, no further probing."""

    kind = "gp_static"

    def __init__(self, config: Mapping[str, Any] | AgpConfig | None = None):
        if isinstance(config, AgpConfig):
            config.recalibration = False
            config.control_interval_s = 0.0
        else:
            config = {**(config or {}), "recalibration": False, "control_interval_s": 0.0}
        super().__init__(config)
