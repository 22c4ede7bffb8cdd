"""Characteristic-diagram compensation behind the shared AdaptiveModel protocol (kind ``"cd"``).

The CD papers (``shared/spec/characteristic-diagrams.md``) describe a base model of static
maps from temperatures to errors, improved in production by a *load-case update* fitted to
measurements of the running load case. As an adaptive model:

* **calibration phase** (no pre-trained base given): probe every
  ``calibration_probe_interval_s`` for ``min_calibration_s``; then choose the inputs of each
  component's CD by the forward heuristic of [003] from the candidates (every temperature and,
  with ``use_gradients``, its gradient in K/h over ``gradient_window_s``) and fit the base CDs;
* **compensation phase**: the prediction is base + update; a probe every
  ``update_probe_interval_s``; after every ``update_batch`` new measurements the load-case update
  of [002 §3.2] (weight-decay loop, original data as anchors) is recomputed from *all*
  measurements since the base was fitted (the paper found repeating an update on the same load
  case gains nothing, so one update model is kept and replaced).

With ``type_model`` and ``type_inputs`` the candidates also hold soft sensors of the machine
type (``twin:<node>`` / ``twin:<error>``, :mod:`talc_model.type_inputs`: the type's nominal twin
stepped from the machine inputs), as levels; their state is part of the model's.

CDs carry no predictive variance; the reported std is the RMS of the last
``uncertainty_window`` prediction errors seen by the probe *before* learning from them (an
honest out-of-sample figure), NaN until there are any. Inputs outside the grid are clamped.
No rclpy here.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from talc_model.adaptive_model import (PHASE_CALIBRATION, PHASE_COMPENSATION, ModelStatusData, prior_model_class,
                                       register_model)
from talc_model.cd.input_selection import forward_selection
from talc_model.cd.diagram import CharacteristicDiagram, load_case_update
from talc_model.probing.hold_fallback import HoldFallback, probe_totals
from talc_model.type_inputs import held_input_labels, load_soft_sensors, restore_soft_sensors
from thermal_comp_common.components import FIVE_AXIS_COMPONENTS


class CdModelError(ValueError):
    """Bad configuration or state of the CD model; the message names the key and value."""


@dataclass
class CdConfig:
    components: list[str] = field(default_factory=lambda: list(FIVE_AXIS_COMPONENTS))
    sensors: list[str] | None = None          # None: all temperatures seen at the first update
    use_gradients: bool = True
    gradient_window_s: float = 600.0
    #: first-order low-passes of every temperature (time constants, s): candidates that carry the
    #: structure's thermal lag, which static maps of the present temperatures miss (docs/prior.md)
    lowpass_time_constants_s: list[float] = field(default_factory=list)
    #: the machine type (preset name or YAML) whose soft sensors ``type_inputs`` names
    type_model: str = ""
    #: soft sensors of ``type_model`` that are candidate inputs (levels, after the low-passes)
    type_inputs: list[str] = field(default_factory=list)
    #: beyond the training range the diagrams continue linearly along the soft-sensor inputs
    #: (the type's predicted error stays a linear map of the unit's; clamping it cut a 60-um
    #: excursion to the prior's 40 um) and clamp along the others (the papers')
    extrapolate_type_inputs: bool = False
    max_inputs: int = 3
    n_intervals: int = 4
    smoothing: float = 1e-4
    calibration_probe_interval_s: float = 1800.0
    min_calibration_s: float = 24 * 3600.0
    update_probe_interval_s: float = 4 * 3600.0
    update_batch: int = 6
    uncertainty_window: int = 10
    #: RMSE floor of the load-case update's stop rule (about the probe noise; 0 = the paper's rule)
    update_rmse_floor: float = 0.0
    probe_duration_s: float = 95.0
    seed: int = 0
    #: per component, hold the last probe while the model's prequential score is not better than
    #: holding it (talc_model.probing.hold_fallback; False = always the model's prediction)
    hold_fallback: bool = True

    @classmethod
    def from_mapping(cls, config: Mapping[str, Any]) -> "CdConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(config) - known)
        if unknown:
            raise CdModelError(f"cd config: unknown key(s) {unknown} (known: {sorted(known)})")
        cfg = cls(**dict(config))
        if not cfg.components:
            raise CdModelError("cd config: 'components' is empty")
        for name in ("gradient_window_s", "calibration_probe_interval_s", "update_probe_interval_s",
                     "probe_duration_s"):
            v = getattr(cfg, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise CdModelError(f"cd config: '{name}' must be a positive number, got {v!r}")
        for tau in cfg.lowpass_time_constants_s:
            if not (isinstance(tau, (int, float)) and math.isfinite(tau) and tau > 0):
                raise CdModelError(f"cd config: 'lowpass_time_constants_s' must hold positive numbers, got {tau!r}")
        for name in ("max_inputs", "n_intervals", "update_batch", "uncertainty_window"):
            v = getattr(cfg, name)
            if not (isinstance(v, int) and v >= 1):
                raise CdModelError(f"cd config: '{name}' must be an integer >= 1, got {v!r}")
        if not (isinstance(cfg.update_rmse_floor, (int, float)) and math.isfinite(cfg.update_rmse_floor)
                and cfg.update_rmse_floor >= 0):
            raise CdModelError(f"cd config: 'update_rmse_floor' must be a number >= 0, got {cfg.update_rmse_floor!r}")
        if cfg.type_inputs and not cfg.type_model:
            raise CdModelError(f"cd config: 'type_inputs' {cfg.type_inputs} are soft sensors of the machine type, "
                               "but 'type_model' names no type (a preset name or a machine YAML)")
        if not isinstance(cfg.hold_fallback, bool):
            raise CdModelError(f"cd config: 'hold_fallback' must be true or false, got {cfg.hold_fallback!r}")
        if not (isinstance(cfg.min_calibration_s, (int, float)) and cfg.min_calibration_s >= 0):
            raise CdModelError(f"cd config: 'min_calibration_s' must be >= 0, got {cfg.min_calibration_s!r}")
        return cfg


def extrapolated_axes(config: CdConfig, candidate_names: list[str], cols: list[int] | None) -> list[bool] | bool:
    """Per chosen column: does the diagram extrapolate along it (a soft sensor, with
    ``extrapolate_type_inputs``)? False for all without columns."""
    if cols is None or not config.extrapolate_type_inputs:
        return False
    return [candidate_names[i] in config.type_inputs for i in cols]


@register_model("cd")
class CharacteristicDiagramModel:
    """Characteristic diagrams with load-case updates (see the module docstring)."""

    kind = "cd"

    def __init__(self, config: Mapping[str, Any] | None = None):
        self.config = CdConfig.from_mapping(config or {})
        self.component_names = list(self.config.components)
        self.phase = PHASE_CALIBRATION
        self.sensor_names: list[str] | None = list(self.config.sensors) if self.config.sensors else None
        self.recent: deque = deque()            # (t, temperatures) within the gradient window
        self.current: np.ndarray | None = None  # candidate input vector
        self.lowpass: np.ndarray | None = None  # low-passed temperatures, one row per time constant
        self.t_input: float | None = None       # time of the last update_inputs
        self.excluded: list[str] = []
        self.held: dict[str, float] = {}
        self.base_u: list[list[float]] = []     # candidate vectors the base was trained on
        self.base_y: dict[str, list[float]] = {c: [] for c in self.component_names}
        self.new_u: list[list[float]] = []      # measurements since the base was fitted
        self.new_y: dict[str, list[float]] = {c: [] for c in self.component_names}
        self.inputs: dict[str, list[int]] = {}
        self.base: dict[str, CharacteristicDiagram] = {}
        self.update: dict[str, CharacteristicDiagram] = {}
        self.errors: dict[str, deque] = {c: deque(maxlen=self.config.uncertainty_window)
                                         for c in self.component_names}
        self.t_start: float | None = None
        self.t_last_probe: float | None = None
        self.probing_cycles = 0
        self.failed_probing_cycles = 0
        self.parameter_updates = 0
        self.pending_since_update = 0
        self.message = "calibration: collecting measurements"
        #: the machine type's soft sensors (``type_inputs``), stepped at every update_inputs
        self.soft_sensors = (load_soft_sensors(self.config.type_model, self.config.type_inputs, "cd config",
                                               "'type_inputs'") if self.config.type_inputs else None)
        self._key = 0
        self._cache: tuple[int, dict, dict] | None = None
        #: per component: the model's prediction or its last probe (probing.hold_fallback)
        self.hold = HoldFallback(self.component_names, self.config.hold_fallback,
                                 horizon_s=self.config.update_probe_interval_s)

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> "CharacteristicDiagramModel":
        return cls(config)

    # ------------------------------------------------------------------ inputs
    @property
    def candidate_names(self) -> list[str]:
        """temperatures, their low-passes (``T~tau``, tau in h), the type's soft sensors
        (``type_inputs``), the temperatures' gradients (``dT/dt``)."""
        names = list(self.sensor_names or [])
        lows = [f"{n}~{tau / 3600.0:g}h" for tau in self.config.lowpass_time_constants_s for n in names]
        return names + lows + list(self.config.type_inputs) + (
            [f"d{n}/dt" for n in names] if self.config.use_gradients else [])

    @property
    def level_columns(self) -> int:
        """How many leading candidates are levels (the temperatures, their low-passes, the soft sensors)."""
        return len(self.sensor_names or []) * (1 + len(self.config.lowpass_time_constants_s)) + len(
            self.config.type_inputs)

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        if not math.isfinite(t_s):
            raise CdModelError(f"update_inputs: t_s {t_s!r} is not a finite time")
        if self.t_start is None:
            self.t_start = float(t_s)
        if self.sensor_names is None:
            self.sensor_names = sorted(temperatures)
            if not self.sensor_names:
                raise CdModelError("update_inputs: no temperatures: the CDs have no input")
        temps, excluded = [], []
        for name in self.sensor_names:
            v = float(temperatures.get(name, math.nan))
            if math.isfinite(v):
                self.held[name] = v
            else:
                excluded.append(name)
                v = self.held.get(name, math.nan)
            temps.append(v)
        self.excluded = excluded
        temps = np.asarray(temps)
        taus = np.asarray(self.config.lowpass_time_constants_s, float)[:, None]
        if self.lowpass is None or self.t_input is None or not np.all(np.isfinite(self.lowpass)):
            self.lowpass = np.repeat(temps[None, :], taus.shape[0], axis=0)
        else:
            self.lowpass = self.lowpass + (temps - self.lowpass) * (1.0 - np.exp(-max(t_s - self.t_input, 0.0) / taus))
        self.t_input = float(t_s)
        levels = np.concatenate([temps, self.lowpass.ravel(), self._soft_values(t_s, temperatures, machine_state)])
        self.recent.append((float(t_s), temps))
        while len(self.recent) > 2 and t_s - self.recent[1][0] >= self.config.gradient_window_s:
            self.recent.popleft()
        if self.config.use_gradients:
            t0, x0 = self.recent[0]
            grad = (temps - x0) / ((t_s - t0) / 3600.0) if t_s > t0 else np.zeros_like(temps)
            self.current = np.concatenate([levels, grad])
        else:
            self.current = levels
        self._key += 1

    def _soft_values(self, t_s: float, temperatures: Mapping[str, float],
                     machine_state: Mapping[str, float]) -> np.ndarray:
        """The ``type_inputs`` soft sensors at ``t_s`` (the type's twin stepped to it)."""
        if self.soft_sensors is None:
            return np.zeros(0)
        values = self.soft_sensors.update(t_s, temperatures, machine_state)
        return np.asarray([values[n] for n in self.config.type_inputs], float)

    # ------------------------------------------------------------------ prediction
    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        """The compensation: per component the diagrams' prediction or, where it is not worth more
        than the last probe, that probe (:attr:`hold`; the calibration phase holds it anyway)."""
        values, stds = self._predict_raw(t_s)
        return self.hold.output(float(t_s), values, self.phase != PHASE_CALIBRATION), stds

    def _predict_raw(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        if self._cache is not None and self._cache[0] == self._key:
            return dict(self._cache[1]), dict(self._cache[2])
        values, stds = {}, {}
        for c in self.component_names:
            errs = self.errors[c]
            stds[c] = float(np.sqrt(np.mean(np.square(errs)))) if errs else math.nan
            if self.phase == PHASE_CALIBRATION or c not in self.base or self.current is None:
                values[c] = self.base_y[c][-1] if self.base_y[c] else 0.0   # hold the last measurement
                continue
            u = self.current[self.inputs[c]][None, :]
            v = float(self.base[c].predict(u)[0])
            if c in self.update:
                v += float(self.update[c].predict(u)[0])
            values[c] = v
        self._cache = (self._key, dict(values), dict(stds))
        return values, stds

    # ------------------------------------------------------------------ probing
    def _interval(self) -> float:
        return (self.config.calibration_probe_interval_s if self.phase == PHASE_CALIBRATION
                else self.config.update_probe_interval_s)

    def probe_due(self, t_s: float) -> bool:
        return self.t_last_probe is None or t_s - self.t_last_probe >= self._interval()

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        self.failed_probing_cycles += 1
        self.t_last_probe = float(t_s)
        self._key += 1
        self.message = f"probing failed at t={t_s:.0f} s: {reason}"

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        """Learn from a probe (:meth:`_learn`), then score the prediction made before it against
        holding the previous probe (:attr:`hold`)."""
        self._learn(t_s, measured, applied_compensation)
        self.hold.observe(float(t_s), probe_totals(measured, applied_compensation))

    def _learn(self, t_s: float, measured: Mapping[str, float],
               applied_compensation: Mapping[str, float]) -> None:
        if self.current is None:
            raise CdModelError("add_measurement: no inputs yet (call update_inputs first)")
        self.t_last_probe = float(t_s)
        self._key += 1
        totals = {}
        for c in self.component_names:
            v = measured.get(c, math.nan)
            a = applied_compensation.get(c, 0.0)
            a = 0.0 if a is None or not math.isfinite(float(a)) else float(a)
            if v is None or not math.isfinite(float(v)):
                self.failed_probing_cycles += 1
                self.message = f"measurement at t={t_s:.0f} s lacks component {c!r}; not learned from"
                return
            totals[c] = float(v) + a
        if not np.all(np.isfinite(self.current)):
            self.failed_probing_cycles += 1
            self.message = f"measurement at t={t_s:.0f} s: inputs {self.excluded} never valid; not learned from"
            return
        self.probing_cycles += 1
        if self.phase == PHASE_CALIBRATION:
            self.base_u.append(self.current.tolist())
            for c, v in totals.items():
                self.base_y[c].append(v)
            elapsed = t_s - (self.t_start if self.t_start is not None else t_s)
            if elapsed >= self.config.min_calibration_s and len(self.base_u) >= 2 ** self.config.max_inputs + 2:
                self._fit_base()
                self.phase = PHASE_COMPENSATION
                self.message = f"base diagrams fitted at t={t_s:.0f} s on {len(self.base_u)} measurements"
            self._cache = None
            return
        predicted, _ = self._predict_raw(t_s)
        for c, v in totals.items():
            self.errors[c].append(v - predicted[c])
        self.new_u.append(self.current.tolist())
        for c, v in totals.items():
            self.new_y[c].append(v)
        self.pending_since_update += 1
        if self.pending_since_update >= self.config.update_batch:
            self._fit_update()
            self.message = f"load-case update at t={t_s:.0f} s from {len(self.new_u)} measurements"
        self._cache = None

    def _make_cd(self, cols: list[int] | None = None) -> CharacteristicDiagram:
        """A diagram of the configured grid; on the candidate columns ``cols`` it extrapolates
        along the soft sensors with ``extrapolate_type_inputs``."""
        return CharacteristicDiagram(n_intervals=self.config.n_intervals, smoothing=self.config.smoothing,
                                     extrapolate=extrapolated_axes(self.config, self.candidate_names, cols))

    def _fit_base(self) -> None:
        u = np.asarray(self.base_u)
        for c in self.component_names:
            y = np.asarray(self.base_y[c])
            steps = forward_selection(u, y, max_inputs=self.config.max_inputs, make_cd=self._make_cd,
                                      seed=self.config.seed, min_relative_gain=0.05)
            self.inputs[c] = list(steps[-1].subset)
            self.base[c] = self._make_cd(self.inputs[c]).fit(u[:, self.inputs[c]], y)
        self.update = {}
        self.parameter_updates += 1

    def _fit_update(self) -> None:
        u0, u1 = np.asarray(self.base_u), np.asarray(self.new_u)
        for c in self.component_names:
            cols = self.inputs[c]
            res = load_case_update(self.base[c].predict, u0[:, cols], self.base_y[c], u1[:, cols],
                                   self.new_y[c], make_cd=self._make_cd, rmse_floor=self.config.update_rmse_floor)
            self.update[c] = res.update
        self.pending_since_update = 0
        self.parameter_updates += 1

    # ------------------------------------------------------------------ status and state
    def status(self, t_s: float) -> ModelStatusData:
        elapsed = 0.0 if self.t_start is None else max(t_s - self.t_start, 0.0)
        probing = (self.probing_cycles + self.failed_probing_cycles) * self.config.probe_duration_s
        _, stds = self._predict_raw(t_s)
        finite = [s for s in stds.values() if math.isfinite(s)]
        return ModelStatusData(
            phase=self.phase, probing_cycles=self.probing_cycles, failed_probing_cycles=self.failed_probing_cycles,
            parameter_updates=self.parameter_updates, training_samples=len(self.base_u) + len(self.new_u),
            q_prod_pct=100.0 if elapsed <= 0 else max(0.0, 100.0 * (1.0 - probing / elapsed)),
            next_probing_due_s=(self.t_start or 0.0) if self.t_last_probe is None else self.t_last_probe + self._interval(),
            max_uncertainty=max(finite) if finite else math.nan,
            excluded_sensor_ids=list(self.excluded) + held_input_labels(self.soft_sensors),
            message=self.message + self.hold.note())

    def to_state(self) -> dict:
        return {"kind": self.kind, "config": asdict(self.config), "phase": self.phase,
                "sensor_names": self.sensor_names, "held": self.held, "excluded": self.excluded,
                "recent": [[t, x.tolist()] for t, x in self.recent],
                "current": None if self.current is None else self.current.tolist(),
                "lowpass": None if self.lowpass is None else self.lowpass.tolist(), "t_input": self.t_input,
                "base_u": self.base_u, "base_y": self.base_y, "new_u": self.new_u, "new_y": self.new_y,
                "inputs": self.inputs, "base": {c: cd.to_state() for c, cd in self.base.items()},
                "update": {c: cd.to_state() for c, cd in self.update.items()},
                "errors": {c: list(e) for c, e in self.errors.items()},
                "t_start": self.t_start, "t_last_probe": self.t_last_probe,
                "probing_cycles": self.probing_cycles, "failed_probing_cycles": self.failed_probing_cycles,
                "parameter_updates": self.parameter_updates, "pending_since_update": self.pending_since_update,
                "message": self.message,
                "soft_sensors": None if self.soft_sensors is None else self.soft_sensors.to_state(),
                "hold_fallback": self.hold.to_state()}

    @classmethod
    def from_state(cls, state: dict) -> "CharacteristicDiagramModel":
        if state.get("kind") != cls.kind:
            raise CdModelError(f"model state: kind {state.get('kind')!r}, expected {cls.kind!r}")
        if cls is CharacteristicDiagramModel and state.get("prior") is not None:   # resumes with its prior
            return prior_model_class(cls.kind).from_state(state)
        try:
            m = cls(state["config"])
            for key in ("phase", "sensor_names", "held", "excluded", "base_u", "base_y", "new_u", "new_y",
                        "inputs", "t_start", "t_last_probe", "probing_cycles", "failed_probing_cycles",
                        "parameter_updates", "pending_since_update", "message"):
                setattr(m, key, state[key])
            m.recent = deque((float(t), np.asarray(x, dtype=float)) for t, x in state["recent"])
            m.current = None if state["current"] is None else np.asarray(state["current"], dtype=float)
            m.lowpass = None if state.get("lowpass") is None else np.asarray(state["lowpass"], dtype=float).reshape(
                len(m.config.lowpass_time_constants_s), len(m.sensor_names or []))
            m.t_input = state.get("t_input")
            m.base = {c: CharacteristicDiagram.from_state(s) for c, s in state["base"].items()}
            m.update = {c: CharacteristicDiagram.from_state(s) for c, s in state["update"].items()}
            m.errors = {c: deque(e, maxlen=m.config.uncertainty_window) for c, e in state["errors"].items()}
            m.message += restore_soft_sensors(m.soft_sensors, state)
            m.hold = HoldFallback.from_state(state.get("hold_fallback"), m.component_names, m.config.hold_fallback,
                                             m.config.update_probe_interval_s)
        except KeyError as exc:
            raise CdModelError(f"model state: missing key {exc}") from None
        return m
