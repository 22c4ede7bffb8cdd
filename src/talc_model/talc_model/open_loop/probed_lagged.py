"""The streaming shell shared by the adaptive open-loop models (probe gain update, probe refit).

A :class:`ProbedLaggedModel` is an :class:`~talc_model.adaptive_model.AdaptiveModel` around the
lagged-temperature ridge (:mod:`talc_model.open_loop.lagged_temperature_model`):

- its features are :func:`lagged_features` computed row by row (:class:`LaggedFeatureStream`:
  the same causal filters, relative to the first temperatures seen);
- **calibration**: it probes every ``calibration_interval_s`` until ``calibration_probes``
  measurements, then fits one ridge per error component on them (standardised features,
  ``alpha``), as ``evaluate`` fits it on its training rows;
- **compensation**: it probes every ``probe_every_s``; what a probe changes is the subclass's
  rule (:meth:`_learn`), and so is the compensation between probes (:meth:`_value`).

The model learns from the total error ``measured + applied_compensation``. It reports no
uncertainty (NaN std). No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION, PHASE_COMPENSATION, ModelStatusData
from talc_model.open_loop.lagged_temperature_model import LaggedTemperatureModel
from thermal_comp_common.components import FIVE_AXIS_COMPONENTS
from thermal_comp_common.metrics import q_prod

#: configuration keys of every probed lagged model and their defaults
BASE_DEFAULTS: dict[str, Any] = {
    "component_names": list(FIVE_AXIS_COMPONENTS),
    "sensor_ids": [],                    # empty: every sensor of the first update, sorted
    "taus_s": [1800.0, 7200.0],
    "alpha": 10.0,
    "calibration_probes": 24,
    "calibration_interval_s": 1800.0,
    "probe_every_s": 7200.0,
    "probe_duration_s": 95.0,
}


#: the fitted attributes of a component's ridge that its state keeps
RIDGE_FIELDS = ("mean", "scale", "coef", "intercept")


def _finite_or_none(values) -> list:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, float).ravel()]


def _from_list(values) -> np.ndarray:
    return np.asarray([math.nan if v is None else float(v) for v in values], float)


class LaggedFeatureStream:
    """:func:`~talc_model.open_loop.lagged_temperature_model.lagged_features` one row at a time:
    [T - T_ref, LP_tau(T - T_ref) for each tau], T_ref the first row seen, NaN features 0 and a NaN
    reading holding its filter (as the batch filters do)."""

    def __init__(self, taus_s):
        self.taus_s = [float(t) for t in taus_s]
        self.reference: np.ndarray | None = None
        self.states: list[np.ndarray] = []
        self.last_t: float | None = None

    def update(self, t_s: float, values: np.ndarray) -> np.ndarray:
        values = np.asarray(values, float)
        if self.reference is None:
            self.reference = values.copy()
            d = values - self.reference
            self.states = [np.where(np.isfinite(d), d, 0.0) for _ in self.taus_s]
        else:
            d = values - self.reference
            ok = np.isfinite(d)
            dt = max(float(t_s) - float(self.last_t), 0.0)
            for tau, s in zip(self.taus_s, self.states):
                a = math.exp(-dt / tau) if tau > 0 else 0.0
                s[ok] = a * s[ok] + (1.0 - a) * d[ok]
        self.last_t = float(t_s)
        blocks = [d] + [d if tau == 0 else s for tau, s in zip(self.taus_s, self.states)]
        x = np.concatenate(blocks)
        return np.where(np.isfinite(x), x, 0.0)

    def to_state(self) -> dict[str, Any]:
        return {"taus_s": self.taus_s, "last_t": self.last_t,
                "reference": None if self.reference is None else _finite_or_none(self.reference),
                "states": [s.tolist() for s in self.states]}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "LaggedFeatureStream":
        s = cls(state["taus_s"])
        s.last_t = state["last_t"]
        s.reference = None if state["reference"] is None else _from_list(state["reference"])
        s.states = [np.asarray(v, float) for v in state["states"]]
        return s


class ProbedLaggedModel:
    """Calibration, probing schedule, status and persistence of a lagged ridge adapted by probes;
    subclasses set ``DEFAULTS`` (extra keys) and the rule of a compensation probe."""

    kind: str
    DEFAULTS: dict[str, Any] = {}

    def __init__(self, config: Mapping[str, Any] | None = None):
        cfg = {**BASE_DEFAULTS, **self.DEFAULTS}
        config = dict(config or {})
        unknown = sorted(set(config) - set(cfg))
        if unknown:
            raise ValueError(f"{type(self).__name__} config: unknown key {unknown[0]!r} (known: {sorted(cfg)})")
        cfg.update(config)
        cfg["component_names"] = [str(c) for c in cfg["component_names"]]
        cfg["sensor_ids"] = [str(s) for s in cfg["sensor_ids"]]
        cfg["taus_s"] = [float(t) for t in cfg["taus_s"]]
        for k in ("calibration_interval_s", "probe_every_s", "probe_duration_s"):
            if not (isinstance(cfg[k], (int, float)) and math.isfinite(cfg[k]) and cfg[k] > 0):
                raise ValueError(f"{type(self).__name__} config '{k}': {cfg[k]!r} must be a finite number > 0")
        n = cfg["calibration_probes"]
        if not isinstance(n, int) or isinstance(n, bool) or n < 2:
            raise ValueError(f"{type(self).__name__} config 'calibration_probes': {n!r} must be an integer >= 2")
        if not cfg["component_names"]:
            raise ValueError(f"{type(self).__name__} config 'component_names': empty")
        LaggedTemperatureModel(cfg["taus_s"], cfg["alpha"])._checked_params()     # names a bad tau or alpha
        self._check(cfg)
        self.config = cfg
        self.component_names = list(cfg["component_names"])
        self.sensor_ids = list(cfg["sensor_ids"])
        self.stream = LaggedFeatureStream(cfg["taus_s"])
        self.x: np.ndarray | None = None                 # the features at the last update
        self.t_start: float | None = None
        self.last_probe_s: float | None = None
        self.calibration_x: list[list[float]] = []
        self.calibration_y: dict[str, list[float | None]] = {c: [] for c in self.component_names}
        self.ridges: dict[str, LaggedTemperatureModel] | None = None   # per component, once fitted
        self.last: dict[str, Any] = {}                   # per component: the last probe's reading and features
        self.probing_cycles = 0
        self.failed_probing_cycles = 0
        self.parameter_updates = 0

    def _check(self, cfg: Mapping[str, Any]) -> None:
        """Validate the subclass's own configuration keys."""

    # ------------------------------------------------------------------ the streaming protocol

    @property
    def phase(self) -> str:
        return PHASE_CALIBRATION if self.ridges is None else PHASE_COMPENSATION

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        if not self.sensor_ids:
            self.sensor_ids = sorted(temperatures)
        values = [float(temperatures.get(s, math.nan)) for s in self.sensor_ids]
        self.x = self.stream.update(t_s, values)
        if self.t_start is None:
            self.t_start = float(t_s)

    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        stds = {c: math.nan for c in self.component_names}
        if self.ridges is None or self.x is None:         # calibration: hold the last probe
            return {c: self._held(c) for c in self.component_names}, stds
        return {c: float(self._value(c, self.x)) for c in self.component_names}, stds

    def _held(self, c: str) -> float:
        ys = [v for v in self.calibration_y[c] if v is not None]
        return ys[-1] if ys else 0.0

    def _interval_s(self) -> float:
        return self.config["calibration_interval_s" if self.ridges is None else "probe_every_s"]

    def probe_due(self, t_s: float) -> bool:
        return self.x is not None and (self.last_probe_s is None or t_s - self.last_probe_s >= self._interval_s())

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        if self.x is None:
            raise ValueError("add_measurement: no inputs yet (call update_inputs first)")
        total = {c: float(measured.get(c, math.nan)) + float(applied_compensation.get(c, 0.0))
                 for c in self.component_names}
        self.probing_cycles += 1
        self.last_probe_s = float(t_s)
        if self.ridges is None:
            self.calibration_x.append(self.x.tolist())
            for c in self.component_names:
                self.calibration_y[c].append(total[c] if math.isfinite(total[c]) else None)
            if len(self.calibration_x) >= self.config["calibration_probes"]:
                self._fit()
            return
        for c in self.component_names:
            if math.isfinite(total[c]):
                self._learn(c, self.x, total[c])
        self.parameter_updates += 1

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        self.failed_probing_cycles += 1
        self.last_probe_s = float(t_s)

    def status(self, t_s: float) -> ModelStatusData:
        elapsed = 0.0 if self.t_start is None else max(t_s - self.t_start, 0.0)
        n = self.probing_cycles + self.failed_probing_cycles
        due = math.inf if self.last_probe_s is None else self.last_probe_s + self._interval_s()
        return ModelStatusData(phase=self.phase, probing_cycles=self.probing_cycles,
                               failed_probing_cycles=self.failed_probing_cycles,
                               parameter_updates=self.parameter_updates, training_samples=len(self.calibration_x),
                               q_prod_pct=q_prod(n, elapsed, self.config["probe_duration_s"]),
                               next_probing_due_s=due)

    # ------------------------------------------------------------------ calibration and the rule

    def _fit(self) -> None:
        """One ridge per component on the calibration probes, then the subclass's start."""
        x = np.asarray(self.calibration_x, float)
        self.ridges = {}
        for c in self.component_names:
            y = _from_list(self.calibration_y[c])
            self.ridges[c] = LaggedTemperatureModel(self.config["taus_s"], self.config["alpha"]).fit(x, y)
            ok = np.flatnonzero(np.isfinite(y))
            self._start(c, x[ok], y[ok])

    def standardised(self, c: str, x: np.ndarray) -> np.ndarray:
        r = self.ridges[c]
        return (np.asarray(x, float) - r.mean_) / r.scale_

    def _start(self, c: str, x: np.ndarray, y: np.ndarray) -> None:
        """After the fit of component ``c`` on its finite calibration rows (``x``, ``y``)."""
        raise NotImplementedError

    def _learn(self, c: str, x: np.ndarray, y: float) -> None:
        """A compensation probe read total error ``y`` of ``c`` at features ``x``."""
        raise NotImplementedError

    def _value(self, c: str, x: np.ndarray) -> float:
        """The compensation of ``c`` at features ``x``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ persistence

    def _ridge(self, fields: Mapping[str, Any]) -> LaggedTemperatureModel:
        r = LaggedTemperatureModel(self.config["taus_s"], self.config["alpha"])
        for k in RIDGE_FIELDS:
            setattr(r, k + "_", float(fields[k]) if k == "intercept" else np.asarray(fields[k], float))
        return r

    def _rule_state(self) -> dict[str, Any]:
        return {}

    def _load_rule_state(self, state: Mapping[str, Any]) -> None:
        """Restore what :meth:`_rule_state` wrote."""

    def to_state(self) -> dict[str, Any]:
        ridges = None if self.ridges is None else {
            c: {k: np.asarray(getattr(r, k + "_")).tolist() for k in RIDGE_FIELDS} for c, r in self.ridges.items()}
        return {"kind": self.kind, "config": dict(self.config), "sensor_ids": list(self.sensor_ids),
                "stream": self.stream.to_state(), "x": None if self.x is None else self.x.tolist(),
                "t_start": self.t_start, "last_probe_s": self.last_probe_s,
                "calibration_x": self.calibration_x, "calibration_y": self.calibration_y, "ridges": ridges,
                "probing_cycles": self.probing_cycles, "failed_probing_cycles": self.failed_probing_cycles,
                "parameter_updates": self.parameter_updates, "rule": self._rule_state()}

    @classmethod
    def from_state(cls, state: dict) -> "ProbedLaggedModel":
        try:
            m = cls(state["config"])
            m.sensor_ids = list(state["sensor_ids"])
            m.stream = LaggedFeatureStream.from_state(state["stream"])
            m.x = None if state["x"] is None else np.asarray(state["x"], float)
            m.t_start, m.last_probe_s = state["t_start"], state["last_probe_s"]
            m.calibration_x = [list(r) for r in state["calibration_x"]]
            m.calibration_y = {c: list(v) for c, v in state["calibration_y"].items()}
            m.ridges = None if state["ridges"] is None else {
                c: m._ridge(r) for c, r in state["ridges"].items()}
            m.probing_cycles = int(state["probing_cycles"])
            m.failed_probing_cycles = int(state["failed_probing_cycles"])
            m.parameter_updates = int(state["parameter_updates"])
            if m.ridges is not None:
                m._load_rule_state(state["rule"])
        except KeyError as exc:
            raise ValueError(f"{cls.__name__} state: missing key {exc}") from None
        return m
