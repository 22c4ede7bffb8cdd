"""Adaptive Gaussian process (AGP) thermal-error model of the Swiss-type-lathe thesis (Fig. 5.13).

:class:`AdaptiveGaussianProcess` (kind ``"agp"``) behind the shared
:class:`~talc_model.adaptive_model.AdaptiveModel` protocol: a calibration phase that compensates
with the measured error and probes every part cycle until N_min points and the minimum
calibration time; then a prediction phase that probes when the predictive std exceeds sigma_max
(recalibration) or a control measurement is due. :class:`StaticGaussianProcess` (``"gp_static"``)
never recalibrates (thesis Table 6.1). The GP is :mod:`talc_model.agp.gaussian_process`, the offset
models :mod:`talc_model.agp.offset_model`. Spec: ``shared/spec/agp-swiss-lathe-thesis.md``; the
choices for the thesis's gaps, one config key each: docs/agp_cd.md. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from talc_model.adaptive_model import (PHASE_CALIBRATION, PHASE_COMPENSATION, ModelStatusData,
                                       prior_model_class, register_model)
from talc_model.agp.gaussian_process import AgpConfigError, ArdGaussianProcess
from talc_model.agp.offset_model import OffsetModel
from talc_model.probing.hold_fallback import HoldFallback, probe_totals
from talc_model.open_loop.sensor_selection import calibration_points_needed


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
    #: per component, hold the last probe while the model's prequential score is not better than
    #: holding it (talc_model.probing.hold_fallback; False = always the model's prediction). A
    #: probe older than its score covers is not held (the AGP may stop probing for hours)
    hold_fallback: bool = True

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
        if not isinstance(self.hold_fallback, bool):
            raise AgpConfigError(f"agp config: 'hold_fallback' must be true or false, got {self.hold_fallback!r}")
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
        #: per component: the model's prediction or its last probe (probing.hold_fallback)
        self.hold = HoldFallback(self.component_names, cfg.hold_fallback, horizon_s=cfg.control_interval_s)

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
        """The compensation: per component the model's prediction or, where it is not worth more
        than the last probe, that probe (:attr:`hold`; the calibration phase holds it anyway)."""
        values, stds = self._predict_raw(t_s)
        return self.hold.output(float(t_s), values, self._has_prediction()), stds

    def _has_prediction(self) -> bool:
        """Whether the output is the model's own (the calibration phase holds the measured error)."""
        return self.phase != PHASE_CALIBRATION

    def _predict_raw(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
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
        """Learn from a probe (:meth:`_learn`), then score the prediction made before it against
        holding the previous probe (:attr:`hold`)."""
        self._learn(t_s, measured, applied_compensation)
        self.hold.observe(float(t_s), probe_totals(measured, applied_compensation))

    def _learn(self, t_s: float, measured: Mapping[str, float],
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
        _, stds = self._predict_raw(t_s)
        finite = [s for s in stds.values() if math.isfinite(s)]
        return ModelStatusData(phase=self.phase, probing_cycles=self.probing_cycles,
                               failed_probing_cycles=self.failed_probing_cycles, no_good_phases=0,
                               parameter_updates=self.parameter_updates, training_samples=len(self.train_x),
                               q_prod_pct=q, next_probing_due_s=self._next_due(),
                               max_uncertainty=max(finite) if finite else math.nan,
                               excluded_sensor_ids=list(self.excluded), message=self.message + self.hold.note())

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
                "gps": {c: gp.to_state() for c, gp in self.gps.items()}, "hold_fallback": self.hold.to_state()}

    @classmethod
    def from_state(cls, state: dict) -> "AdaptiveGaussianProcess":
        if state.get("kind") != cls.kind:
            raise AgpConfigError(f"model state: kind {state.get('kind')!r}, expected {cls.kind!r}")
        if cls is AdaptiveGaussianProcess and state.get("prior") is not None:   # resumes with its prior
            return prior_model_class(cls.kind).from_state(state)
        try:
            model = cls(state["config"])
            for key in ("phase", "input_names", "held", "excluded", "current_temperatures", "history",
                        "train_x", "train_y", "last_total", "t_start", "t_last_probe", "probing_cycles",
                        "failed_probing_cycles", "parameter_updates", "recalibration_times",
                        "control_measurements", "n_min", "n_groups", "message", "pending_reason"):
                setattr(model, key, state[key])
            model.current_x = None if state["current_x"] is None else np.asarray(state["current_x"], dtype=float)
            model.gps = {c: ArdGaussianProcess.from_state(s) for c, s in state["gps"].items()}
            model.hold = HoldFallback.from_state(state.get("hold_fallback"), model.component_names,
                                                 model.config.hold_fallback, model.config.control_interval_s)
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
