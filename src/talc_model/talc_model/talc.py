"""TALC, Thermal Adaptive Learning Control (Blaser thesis ch. 6): ARX models that learn online.

State machine (thesis §6.2, spec §9.4):

1. **Calibration phase** (CP): probe every ``cp_interval_s``; no compensation (predictions
   are 0). The CP ends "as soon as possible" (``cp_length_h = 0``) when the number of
   measured samples reaches the sum of the maximum orders *and* every component's
   regression matrix with the maximum orders has full rank; with ``cp_length_h > 0`` it
   ends after that time (and full rank). The first fit selects the orders per component
   by :func:`order_selection.select_orders` on a chronological 60/40 split.
2. **Compensation phase**: predict on the model grid (``model_step_s``, 5 min), feeding
   predictions back as the autoregressive outputs; probe every ``post_cp_interval_h``. A
   measurement replaces the prediction in the output history (state update). The stored
   training output is the total error = measured residual + applied compensation (§6.2.4).
3. **No-good phase** (NG): a measured *residual* beyond the action-control limit
   (5 um linear, 15 um/m angular) starts ``ng_measurements`` probes every
   ``ng_interval_min``; then the parameters are updated. A new exceedance during NG is
   ignored (thesis §6.2.3).

Parameter updates: after every NG phase and at the latest every ``update_interval_h``; WLS
on the history with weight 1 on measured samples and ``predicted_weight`` on samples
that only carry predictions, optional exponential forgetting and a data window.
The maximum input order grows with the data (``nb_max`` -> ``nb_max_final``, thesis
Table 6.6: 10 -> 20) once there are ``growth_samples_per_parameter`` measured samples per
parameter; the orders are then selected again.

Choices where the thesis leaves a gap (each is a config field):

- intervals count from the *end* of a cycle (``interval_from_cycle_end``; spec §4.5 [D]:
  a CP period is 300 + 95 s, which reproduces the reported CP productivity of ~75 %);
- measurements fall on the nearest grid sample; CP grid samples without a measurement
  (a 300 + 95 s CP period on a 300 s grid leaves every 4th to 5th sample empty, failed
  cycles too) are filled by linear interpolation between the neighbouring measurements
  (``cp_gap_fill = "interpolate"``, default: thermal errors are smooth over 5 min, and with
  n_a = 5 the alternative would leave no complete regression row), or left out of the
  first fit and then filled with the fitted model's predictions (``"predict"``, exact for
  plants that jump between samples); either way they are flagged "predicted" (low weight);
- inputs are deltas from each input's first finite value; an unavailable input (NaN) holds
  its last value (``input_names`` entries may be differences, ``"a - b"``, for the
  C-axis coolant inlet-outlet temperature difference);
- the standard uncertainty of a prediction is the RMS of the last ``uncertainty_window``
  out-of-sample residuals (measured total error minus the prediction it replaced),
  before that the simulation-mode validation RMS of the first fit;
- a failed probing cycle costs probing time and counts, is never learned from, and the
  schedule continues as if it had been a probe;
- a pre-trained model (``TalcModel.from_pretrained``) starts in the compensation phase on a
  fresh history (errors and inputs relative to the new start) with the trained parameters.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from talc_model.adaptive_model import (ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS, PHASE_CALIBRATION,
                             PHASE_COMPENSATION, PHASE_NO_GOOD, ModelStatusData, register_model)
from talc_model.arx import ArxModel, ArxOrders, RankDeficientError, check_full_rank, fit_arx, regression_matrix
from talc_model.blas_threads import single_thread_blas
from thermal_comp_common.metrics import q_prod
from talc_model.order_selection import CRITERIA, select_orders

STATE_VERSION = 1


@dataclass
class TalcConfig:
    """Every TALC parameter. Defaults: Table 6.1's fixed values (CP interval 5 min, ACL
    5 um / 15 um/m, n_a max 1, n_b max 10) and Table 6.4's for the varied ones (CP ASAP,
    post-CP interval 2 h, NG 12 x 10 min, update interval 24 h)."""

    component_names: list[str] = field(default_factory=lambda: list(FIVE_AXIS_COMPONENTS))
    #: sensor ids / machine-state keys (or "a - b"); empty = all temperatures of the first update
    input_names: list[str] = field(default_factory=list)
    angular_components: list[str] = field(default_factory=lambda: list(ANGULAR_COMPONENTS))
    model_step_s: float = 300.0            # model / prediction grid (thesis: 5 min)
    # --- Table 6.1
    cp_length_h: float = 0.0               # 0 = ASAP (orders and rank)
    cp_interval_s: float = 300.0           # measurement interval in the CP
    post_cp_interval_h: float = 2.0        # measurement interval after the CP (inf = never)
    ng_interval_min: float = 10.0          # measurement interval in a no-good phase
    acl_linear_um: float = 5.0             # action-control limit, linear errors
    acl_angular_um_per_m: float = 15.0     # action-control limit, angular errors
    ng_measurements: float = 12            # measurements per NG phase (inf = stay in NG)
    update_interval_h: float = 24.0        # maximum time between parameter updates (inf = only after NG)
    na_max: int = 1
    nb_max: int = 10
    # --- order selection and growth
    na_min: int = 1
    nb_min: int = 1
    nb_max_final: int = 10                 # n_b max reached once enough data exist (Table 6.6: 20)
    growth_samples_per_parameter: float = 5.0
    nk: int = 0                            # input delay; 0 includes b0 (thesis examples)
    intercept: bool = False
    criterion: str = "mdl"
    train_fraction: float = 0.6
    reselect_orders_on_update: bool = True  # spec §4.5 suggestion; False = refit with fixed orders
    order_search_exhaustive_limit: int = 4000  # above: coordinate search (order_selection)
    #: an input whose range over the training part of the data is at most this (in its own
    #: unit: K, or 1 for an on/off state) has not varied and cannot be identified: it is left
    #: out of the order search (n_b = 0) and of the calibration phase's rank check until it
    #: has varied. This lets one input list serve every cell: e.g. the MWF state flag of a
    #: cell that has not switched MWF on yet (or never does) costs nothing.
    min_input_range: float = 1e-6
    #: accept a *periodic* update only if the new parameters predict the measured history
    #: (TALC predictor: measurements replace predictions, weighted like the fit) no worse than
    #: the old ones. Updates after a no-good phase are always taken: the old parameters are
    #: known to miss the recent measurements, and gating them slows re-learning after a change.
    update_acceptance: bool = True
    #: at updates, score order candidates with the TALC predictor (state updates at the
    #: measurements) instead of pure simulation over the validation part
    select_with_state_updates: bool = False
    # --- robustness to probe noise (gaps of the thesis; see docs/talc.md "Probe noise")
    #: the CP ends no earlier than this many measured samples per parameter of the largest
    #: candidate model (1 ~ the thesis's "sum of the maximum orders"; 2.5 ends the CP of the
    #: 178 h run after 5.7 h, the thesis reports ~6 h)
    cp_min_samples_per_parameter: float = 2.5
    #: longest time constant a fitted model may have: poles beyond exp(-step / tau) are rejected
    #: (a machine tool's thermal time constants are hours; a pole fitted to noise near 1 makes
    #: the simulation drift like an integrator between the sparse probes); inf = off
    max_time_constant_h: float = 24.0
    #: reject models with complex or negative poles (heat conduction has real poles in (0, 1))
    real_positive_poles: bool = False
    #: reject models with an input whose coefficients sum in absolute value to more than this
    #: many times their net (static) gain: a differentiator fitted to slow data amplifies a
    #: faster input change than any it saw (a hall door: 3 K in 25 min); inf = off
    max_input_gain_ratio: float = math.inf
    # --- weighted least squares
    predicted_weight: float = 0.3          # weight of samples that only carry a prediction (see docs)
    resimulate_history_on_update: bool = False  # regenerate predicted samples with new parameters
    cp_gap_fill: str = "interpolate"       # CP grid samples without a measurement: "interpolate"
    #                                        (linear, between the neighbouring measurements) or
    #                                        "predict" (left out of the first fit, then filled with
    #                                        the fitted model's predictions)
    forgetting_factor: float = 1.0         # weight multiplier per forgetting_period_h of age (1 = off)
    forgetting_period_h: float = 24.0
    history_window_h: float = math.inf     # only samples this recent are fitted
    # --- probing
    probe_duration_s: float = 95.0
    interval_from_cycle_end: bool = True
    uncertainty_window: int = 10

    def __post_init__(self) -> None:
        self.component_names = [str(c) for c in self.component_names]
        self.input_names = [str(c) for c in self.input_names]
        self.angular_components = [str(c) for c in self.angular_components]
        for name in ("model_step_s", "cp_interval_s", "ng_interval_min", "probe_duration_s",
                     "forgetting_period_h", "cp_min_samples_per_parameter"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"TALC config '{name}': {v!r} must be a finite number > 0")
        for name in ("cp_length_h", "post_cp_interval_h", "update_interval_h", "history_window_h",
                     "max_time_constant_h", "min_input_range", "max_input_gain_ratio",
                     "acl_linear_um", "acl_angular_um_per_m", "ng_measurements"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
                raise ValueError(f"TALC config '{name}': {v!r} must be a number >= 0 (inf allowed)")
        if self.max_input_gain_ratio < 1:
            raise ValueError(f"TALC config 'max_input_gain_ratio': {self.max_input_gain_ratio!r} must be >= 1 "
                             "(inf = no bound)")
        if self.post_cp_interval_h == 0 or self.ng_measurements == 0:
            raise ValueError("TALC config 'post_cp_interval_h' and 'ng_measurements' must be > 0")
        for name in ("na_max", "nb_max", "na_min", "nb_min", "nb_max_final", "nk", "uncertainty_window",
                     "order_search_exhaustive_limit"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"TALC config '{name}': {v!r} must be an integer >= 0")
        if self.na_min > self.na_max or self.nb_min > self.nb_max or self.nb_max_final < self.nb_max:
            raise ValueError(f"TALC config: need na_min <= na_max, nb_min <= nb_max <= nb_max_final "
                             f"(got {self.na_min}, {self.na_max}, {self.nb_min}, {self.nb_max}, "
                             f"{self.nb_max_final})")
        if self.criterion not in CRITERIA:
            raise ValueError(f"TALC config 'criterion': {self.criterion!r} is not one of {list(CRITERIA)}")
        if not 0 < self.predicted_weight <= 1:
            raise ValueError(f"TALC config 'predicted_weight': {self.predicted_weight!r} must be in (0, 1]")
        if not 0 < self.forgetting_factor <= 1:
            raise ValueError(f"TALC config 'forgetting_factor': {self.forgetting_factor!r} must be in (0, 1]")
        if not 0.1 <= self.train_fraction <= 0.95:
            raise ValueError(f"TALC config 'train_fraction': {self.train_fraction!r} must be in [0.1, 0.95]")
        if self.cp_gap_fill not in ("predict", "interpolate"):
            raise ValueError(f"TALC config 'cp_gap_fill': {self.cp_gap_fill!r} is not 'predict' or 'interpolate'")
        if not self.component_names:
            raise ValueError("TALC config 'component_names': empty")

    @classmethod
    def from_mapping(cls, config: Mapping[str, Any]) -> "TalcConfig":
        """Build from a mapping; a ``preset`` key starts from :data:`PRESETS`; unknown keys raise."""
        config = dict(config)
        preset = config.pop("preset", None)
        values: dict[str, Any] = {}
        if preset is not None:
            if preset not in PRESETS:
                raise ValueError(f"TALC config 'preset': {preset!r} is not one of {sorted(PRESETS)}")
            values.update(PRESETS[preset])
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(config) - known)
        if unknown:
            raise ValueError(f"TALC config: unknown key(s) {unknown} (known: {sorted(known)})")
        values.update(config)
        for k, v in list(values.items()):
            if isinstance(v, str) and v.strip().lower() in ("inf", "infinity", ".inf"):
                values[k] = math.inf
        for name in ("na_max", "nb_max", "na_min", "nb_min", "nb_max_final", "nk", "uncertainty_window",
                     "order_search_exhaustive_limit"):
            v = values.get(name)
            if isinstance(v, float) and v.is_integer():
                values[name] = int(v)
        return cls(**values)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


#: Parameter sets of the thesis (Tables 6.3, 6.4, 6.6, 7.1).
PRESETS: dict[str, dict[str, Any]] = {
    "table_6_4_178h": dict(cp_length_h=0.0, post_cp_interval_h=2.0, ng_interval_min=10.0,
                           ng_measurements=12, update_interval_h=24.0, na_max=5, nb_max=5,
                           nb_max_final=5),
    "table_6_6_144h_mwf": dict(cp_length_h=0.0, post_cp_interval_h=2.0, ng_interval_min=10.0,
                               ng_measurements=12, update_interval_h=12.0, na_max=1, nb_max=10,
                               nb_max_final=20),
    "table_7_1_test_piece": dict(post_cp_interval_h=1.0, ng_interval_min=5.0, ng_measurements=9,
                                 update_interval_h=8.0, na_max=10, nb_max=10, nb_max_final=10),
    "table_6_3_A": dict(cp_length_h=8.5, post_cp_interval_h=10.0, ng_measurements=12, ng_interval_min=30.0),
    "table_6_3_B": dict(cp_length_h=8.5, post_cp_interval_h=2.0, ng_measurements=6, ng_interval_min=30.0),
    "table_6_3_C": dict(cp_length_h=12.0, post_cp_interval_h=2.0, ng_measurements=18, ng_interval_min=5.0),
    "table_6_3_D": dict(cp_length_h=8.5, post_cp_interval_h=3.0, ng_measurements=12, ng_interval_min=10.0),
}


def _parse_input(name: str) -> tuple[str, str | None]:
    """'a - b' -> ('a', 'b'); 'a' -> ('a', None)."""
    if " - " in name:
        a, b = name.split(" - ", 1)
        return a.strip(), b.strip()
    return name.strip(), None


class _Grid:
    """The uniform model grid: inputs, outputs (measured or predicted) per sample."""

    def __init__(self, n_inputs: int, n_outputs: int, capacity: int = 256):
        self.n = 0
        self.u = np.zeros((capacity, n_inputs))
        self.y = np.full((capacity, n_outputs), np.nan)
        self.measured = np.zeros((capacity, n_outputs), dtype=bool)

    def append(self, u_row: np.ndarray) -> int:
        if self.n == self.u.shape[0]:
            cap = 2 * self.u.shape[0]
            self.u = np.resize(self.u, (cap, self.u.shape[1]))
            y = np.full((cap, self.y.shape[1]), np.nan)
            y[: self.n] = self.y[: self.n]
            self.y = y
            m = np.zeros((cap, self.y.shape[1]), dtype=bool)
            m[: self.n] = self.measured[: self.n]
            self.measured = m
        self.u[self.n] = u_row
        self.y[self.n] = np.nan
        self.measured[self.n] = False
        self.n += 1
        return self.n - 1

    def to_state(self) -> dict:
        return {"u": self.u[: self.n].tolist(), "y": [[None if not math.isfinite(v) else v for v in row]
                                                       for row in self.y[: self.n].tolist()],
                "measured": self.measured[: self.n].astype(int).tolist()}

    @classmethod
    def from_state(cls, d: dict, n_inputs: int, n_outputs: int) -> "_Grid":
        u = np.asarray(d["u"], dtype=float).reshape(-1, n_inputs)
        y = np.asarray([[np.nan if v is None else v for v in row] for row in d["y"]],
                       dtype=float).reshape(-1, n_outputs)
        m = np.asarray(d["measured"], dtype=bool).reshape(-1, n_outputs)
        if not (u.shape[0] == y.shape[0] == m.shape[0]):
            raise ValueError(f"TALC state 'grid': u has {u.shape[0]} rows, y {y.shape[0]}, measured {m.shape[0]}")
        g = cls(n_inputs, n_outputs, max(256, u.shape[0]))
        g.n = u.shape[0]
        g.u[: g.n], g.y[: g.n], g.measured[: g.n] = u, y, m
        return g


@register_model("talc")
class TalcModel:
    """The TALC adaptive model (implements :class:`adaptive_model.AdaptiveModel`)."""

    kind = "talc"

    def __init__(self, config: Mapping[str, Any] | TalcConfig | None = None):
        self.config = config if isinstance(config, TalcConfig) else TalcConfig.from_mapping(config or {})
        c = self.config
        self.component_names = list(c.component_names)
        self.input_names: list[str] = list(c.input_names)
        self.t0: float | None = None
        self.t_last: float | None = None
        self.phase = PHASE_CALIBRATION
        self.models: dict[str, ArxModel] = {}
        self.grid: _Grid | None = None
        self.input_ref: dict[str, float] = {}     # reference (first finite) value per input
        self.input_last: dict[str, float] = {}    # last finite delta per input
        self.raw_last: dict[str, float] = {}      # last raw signal value per name
        self.held_inputs: list[str] = []
        self.probing_cycles = 0
        self.failed_probing_cycles = 0
        self.no_good_phases = 0
        self.parameter_updates = 0
        self.ng_left = 0.0
        self.last_probe_t: float | None = None
        self.t_last_update: float | None = None
        self.nb_max_selected = c.nb_max            # max n_b used in the last order selection
        self.out_of_sample: dict[str, list[float]] = {n: [] for n in self.component_names}
        self.message = "calibration phase: waiting for the first measurement"
        self.events: list[dict] = []               # phase transitions and updates (for reports)
        if self.input_names:
            self._init_grid()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> "TalcModel":
        return cls(config)

    def _init_grid(self) -> None:
        self._input_parts = [_parse_input(n) for n in self.input_names]
        self.grid = _Grid(len(self.input_names), len(self.component_names))

    @property
    def step(self) -> float:
        return self.config.model_step_s

    def _t(self, k: int) -> float:
        return self.t0 + k * self.step

    # ------------------------------------------------------------------ inputs and grid
    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        t_s = float(t_s)
        if not math.isfinite(t_s):
            raise ValueError(f"update_inputs: t_s {t_s!r} is not finite")
        if self.grid is None:
            self.input_names = sorted(temperatures)
            if not self.input_names:
                raise ValueError("update_inputs: no temperatures and no configured 'input_names'")
            self._init_grid()
        if self.t0 is None:
            self.t0 = t_s
        elif self.t_last is not None and t_s < self.t_last:
            raise ValueError(f"update_inputs: time {t_s} goes back (last {self.t_last})")
        # grid samples strictly before t_s use the inputs known before this update
        self._advance(t_s, inclusive=False)
        signals = dict(machine_state)
        signals.update(temperatures)
        held = []
        for name, (a, b) in zip(self.input_names, self._input_parts):
            va = signals.get(a, math.nan)
            vb = signals.get(b, 0.0) if b is not None else 0.0
            try:
                v = float(va) - float(vb)
            except (TypeError, ValueError):
                raise ValueError(f"update_inputs: input '{name}': value {va!r} / {vb!r} is not a number") from None
            if math.isfinite(v):
                if name not in self.input_ref:
                    self.input_ref[name] = v
                self.input_last[name] = v - self.input_ref[name]
            else:
                held.append(name)
        self.held_inputs = held
        self.t_last = t_s

    def _current_u(self) -> np.ndarray:
        return np.array([self.input_last.get(n, 0.0) for n in self.input_names])

    def _advance(self, t_s: float, inclusive: bool = True) -> None:
        """Create grid samples up to t_s, predicting their outputs if a model exists."""
        if self.t0 is None:
            self.t0 = t_s
        if self.grid is None:
            return
        eps = 1e-6 * self.step
        while True:
            k = self.grid.n
            tk = self._t(k)
            if tk > t_s + eps or (not inclusive and tk > t_s - eps):
                break
            self.grid.append(self._current_u())
            if self.phase != PHASE_CALIBRATION:
                self._predict_sample(k)

    def _predict_sample(self, k: int) -> None:
        g = self.grid
        for j, name in enumerate(self.component_names):
            if g.measured[k, j]:
                continue
            m = self.models.get(name)
            if m is None:
                continue
            g.y[k, j] = self._predict_with(m, j, k)

    def _predict_with(self, m: ArxModel, j: int, k: int) -> float:
        g = self.grid
        lag = m.orders.max_lag
        if k >= lag:
            y_hist = g.y[: k + 1, j]
            u_hist = g.u[: k + 1]
            kk = k
        else:  # before the start: outputs and input deltas were zero (steady reference state)
            pad = lag - k
            y_hist = np.concatenate([np.zeros(pad), g.y[: k + 1, j]])
            u_hist = np.vstack([np.zeros((pad, g.u.shape[1])), g.u[: k + 1]])
            kk = k + pad
        v = m.predict_one(y_hist, u_hist, kk)
        return v if math.isfinite(v) else 0.0

    def _resimulate_after(self, k: int) -> None:
        for kk in range(k + 1, self.grid.n):
            self._predict_sample(kk)

    # ------------------------------------------------------------------ prediction
    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        t_s = float(t_s)
        self._advance(t_s)
        self._maybe_periodic_update(t_s)
        values: dict[str, float] = {}
        stds: dict[str, float] = {}
        if self.phase == PHASE_CALIBRATION or self.grid is None or self.grid.n == 0:
            for n in self.component_names:
                values[n], stds[n] = 0.0, math.nan
            return values, stds
        k = self.grid.n - 1
        for j, n in enumerate(self.component_names):
            v = self.grid.y[k, j]
            values[n] = float(v) if math.isfinite(v) else 0.0
            stds[n] = self._uncertainty(n)
        return values, stds

    def _uncertainty(self, name: str) -> float:
        res = self.out_of_sample.get(name, [])
        if len(res) >= 3:
            return float(np.sqrt(np.mean(np.square(res[-self.config.uncertainty_window:]))))
        m = self.models.get(name)
        if m is None:
            return math.nan
        v = m.extra.get("validation_rms", m.residual_std)
        return float(v) if v is not None and math.isfinite(v) else math.nan

    # ------------------------------------------------------------------ probing schedule
    def _interval_s(self) -> float:
        c = self.config
        if self.phase == PHASE_CALIBRATION:
            return c.cp_interval_s
        if self.phase == PHASE_NO_GOOD:
            return c.ng_interval_min * 60.0
        return c.post_cp_interval_h * 3600.0

    def next_probe_due_s(self) -> float:
        if self.last_probe_t is None:
            return self.t0 if self.t0 is not None else -math.inf
        gap = self._interval_s()
        if self.config.interval_from_cycle_end:
            gap += self.config.probe_duration_s
        return self.last_probe_t + gap

    def probe_due(self, t_s: float) -> bool:
        self._advance(float(t_s))
        return float(t_s) >= self.next_probe_due_s() - 1e-9

    # ------------------------------------------------------------------ measurements
    def _limit(self, name: str) -> float:
        c = self.config
        return c.acl_angular_um_per_m if name in c.angular_components else c.acl_linear_um

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        t_s = float(t_s)
        self._advance(t_s)
        self.failed_probing_cycles += 1
        self.last_probe_t = t_s
        self.message = f"probing failed at t={t_s:.0f} s (not learned from): {reason}"
        self.events.append({"t_s": t_s, "event": "probe_failed", "reason": reason})

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        t_s = float(t_s)
        if self.grid is None:
            raise ValueError("add_measurement: no inputs yet (call update_inputs first)")
        if self.t0 is not None and t_s < self.t0 - self.step / 2:
            raise ValueError(f"add_measurement: t_s {t_s} is before the model's start {self.t0}")
        unknown = sorted(set(measured) - set(self.component_names))
        if unknown:
            raise ValueError(f"add_measurement: unknown component(s) {unknown} "
                             f"(model has {self.component_names})")
        residual: dict[str, float] = {}
        total: dict[str, float] = {}
        for name, v in measured.items():
            v = float(v)
            if not math.isfinite(v):
                continue  # component not measured this time
            a = applied_compensation.get(name, 0.0)
            a = float(a) if a is not None and math.isfinite(float(a)) else 0.0
            residual[name] = v
            total[name] = v + a
        if not total:
            raise ValueError(f"add_measurement: no finite value in {dict(measured)}")
        self._advance(max(t_s, self.t0))
        k = int(round((t_s - self.t0) / self.step))
        k = max(0, min(k, self.grid.n - 1))
        g = self.grid
        for j, name in enumerate(self.component_names):
            if name not in total:
                continue
            if self.phase != PHASE_CALIBRATION and not g.measured[k, j] and math.isfinite(g.y[k, j]):
                self.out_of_sample[name].append(total[name] - g.y[k, j])
                del self.out_of_sample[name][:-max(1, self.config.uncertainty_window)]
            g.y[k, j] = total[name]
            g.measured[k, j] = True
        self.probing_cycles += 1
        self.last_probe_t = t_s
        if self.phase != PHASE_CALIBRATION:
            self._resimulate_after(k)
        self._after_measurement(t_s, residual)

    def _after_measurement(self, t_s: float, residual: Mapping[str, float]) -> None:
        with single_thread_blas():  # small problems: see blas_threads
            self._phase_logic(t_s, residual)

    def _phase_logic(self, t_s: float, residual: Mapping[str, float]) -> None:
        c = self.config
        if self.phase == PHASE_CALIBRATION:
            if self._cp_complete(t_s):
                self._first_fit(t_s)
            return
        if self.phase == PHASE_COMPENSATION:
            over = {n: r for n, r in residual.items() if abs(r) > self._limit(n)}
            if over:
                self.phase = PHASE_NO_GOOD
                self.ng_left = c.ng_measurements
                self.no_good_phases += 1
                worst = max(over, key=lambda n: abs(over[n]) / self._limit(n))
                self.message = (f"no-good phase {self.no_good_phases}: residual {worst} = "
                                f"{over[worst]:+.2f} beyond the limit {self._limit(worst):g}")
                self.events.append({"t_s": t_s, "event": "no_good", "components": sorted(over)})
            return
        # no-good phase: count its measurements, then update (new exceedances are ignored)
        self.ng_left -= 1
        if self.ng_left <= 0:
            self._update(t_s, "end of no-good phase")
            self.phase = PHASE_COMPENSATION

    # ------------------------------------------------------------------ identification
    def _max_orders(self, active: np.ndarray | None = None) -> ArxOrders:
        """Largest candidate orders; inputs not ``active`` (see :meth:`_active_inputs`) get n_b = 0."""
        c = self.config
        nb = self._nb_max_now()
        if active is None:
            active = np.ones(len(self.input_names), bool)
        return ArxOrders(c.na_max, tuple(nb if a else 0 for a in active), c.nk, c.intercept)

    def _training_split(self, first: int) -> int:
        """End of the training part of the order selection's split of grid rows [first, n)."""
        return first + int(round(self.config.train_fraction * (self.grid.n - first)))

    def _active_inputs(self, first: int, stop: int) -> np.ndarray:
        """Inputs that varied by more than ``min_input_range`` on grid rows [first, stop)."""
        u = self.grid.u[first:stop]
        if u.shape[0] == 0:
            return np.zeros(len(self.input_names), bool)
        return (np.max(u, axis=0) - np.min(u, axis=0)) > self.config.min_input_range

    def _n_measured(self) -> int:
        g = self.grid
        return int(np.max(np.sum(g.measured[: g.n], axis=0))) if g.n else 0

    def _nb_max_now(self) -> int:
        """n_b max that the data support now (grows from nb_max to nb_max_final)."""
        c = self.config
        if c.nb_max_final <= c.nb_max or not self.input_names:
            return c.nb_max
        n = self._n_measured()
        per_input = (n / c.growth_samples_per_parameter - c.na_max - int(c.intercept)) / len(self.input_names)
        return int(min(c.nb_max_final, max(c.nb_max, math.floor(per_input))))

    def _training_outputs(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Outputs of component j on the grid, CP gaps filled by interpolation; measured mask."""
        g = self.grid
        y = g.y[: g.n, j].copy()
        m = g.measured[: g.n, j].copy()
        missing = ~np.isfinite(y)
        if self.config.cp_gap_fill == "interpolate" and np.any(missing) and np.sum(m) >= 2:
            idx = np.flatnonzero(m)
            inside = missing & (np.arange(g.n) > idx[0]) & (np.arange(g.n) < idx[-1])
            y[inside] = np.interp(np.flatnonzero(inside), idx, y[idx])
        return y, m

    def _weights(self, t_now: float, measured: np.ndarray) -> np.ndarray:
        c = self.config
        g = self.grid
        t = self.t0 + np.arange(g.n) * self.step
        w = np.where(measured, 1.0, c.predicted_weight)
        if c.forgetting_factor < 1.0:
            w = w * c.forgetting_factor ** ((t_now - t) / (c.forgetting_period_h * 3600.0))
        if math.isfinite(c.history_window_h):
            w = np.where(t >= t_now - c.history_window_h * 3600.0, w, 0.0)
        return w

    def _cp_complete(self, t_s: float) -> bool:
        c = self.config
        if c.cp_length_h > 0 and t_s - self.t0 < c.cp_length_h * 3600.0:
            return False
        g = self.grid
        measured_any = np.flatnonzero(np.any(np.isfinite(g.y[: g.n]), axis=1))
        first0 = int(measured_any[0]) if measured_any.size else 0
        orders = self._max_orders(self._active_inputs(first0, self._training_split(first0)))
        need = max(orders.order_sum, math.ceil(c.cp_min_samples_per_parameter * orders.n_params))
        if self._n_measured() < need:
            self.message = (f"calibration phase continues: {self._n_measured()} of {need} measured samples "
                            f"({c.cp_min_samples_per_parameter:g} per parameter of the largest model)")
            return False
        g = self.grid
        for j, name in enumerate(self.component_names):
            y, m = self._training_outputs(j)
            # the first fit estimates on the training part of the split: it must be identifiable
            first = int(np.flatnonzero(np.isfinite(y))[0]) if np.any(np.isfinite(y)) else 0
            split = self._training_split(first)
            phi, target, rows = regression_matrix(y[:split], g.u[:split], orders, start=first + orders.max_lag)
            ok = np.isfinite(target) & np.all(np.isfinite(phi), axis=1)
            try:
                check_full_rank(phi[ok], f"{name} regression matrix (training part)")
            except RankDeficientError as exc:
                self.message = f"calibration phase continues: {exc}"
                return False
        return True

    def _select(self, t_s: float, failures: list[str] | None = None) -> dict[str, ArxModel]:
        """Order selection for every component. With ``failures`` (an update), a component
        without an identifiable, admissible candidate is left out (the caller refits its
        current orders) and the reason is appended; without it (the first fit) it raises
        :class:`RankDeficientError`."""
        c = self.config
        g = self.grid
        nb_max = self._nb_max_now()
        models = {}
        for j, name in enumerate(self.component_names):
            y, m = self._training_outputs(j)
            first = int(np.flatnonzero(np.isfinite(y))[0]) if np.any(np.isfinite(y)) else 0
            w = self._weights(t_s, m)
            try:
                sel = self._select_one(y, m, w, first, nb_max)
            except RankDeficientError as exc:
                if failures is None or name not in self.models:
                    raise
                failures.append(f"{name}: {exc}")
                continue
            models[name] = sel.model
        self.nb_max_selected = nb_max
        return models

    def _select_one(self, y: np.ndarray, m: np.ndarray, w: np.ndarray, first: int, nb_max: int):
        """Order selection on the inputs that have varied on the training part of the split;
        the others get n_b = 0 in the returned model (see ``min_input_range``)."""
        c = self.config
        g = self.grid
        active = self._active_inputs(first, self._training_split(first))
        sel = select_orders(y[first:], g.u[first: g.n][:, active], (c.na_min, c.na_max), (c.nb_min, nb_max),
                            nk=c.nk, intercept=c.intercept, criterion=c.criterion,
                            train_fraction=c.train_fraction, weights=w[first:],
                            measured=m[first:], exhaustive_limit=c.order_search_exhaustive_limit,
                            state_updates=self.phase != PHASE_CALIBRATION and c.select_with_state_updates,
                            max_pole_radius=self._max_pole_radius(),
                            real_positive_poles=c.real_positive_poles,
                            max_input_gain_ratio=c.max_input_gain_ratio)
        if np.all(active):
            return sel
        nb_iter = iter(sel.model.orders.nb)
        full = ArxOrders(sel.model.orders.na, tuple(next(nb_iter) if a else 0 for a in active), c.nk, c.intercept)
        # the parameter vector is (a, b of each input in order, c): inputs with n_b = 0 add nothing
        sel.model = ArxModel(full, sel.model.theta, sel.model.residual_std, sel.model.n_fit_samples,
                             sel.model.extra)
        sel.orders = full
        # an input that began to vary only after the training part (e.g. MWF switched on for the
        # first time a few hours ago) cannot be scored by the split; it enters with the smallest
        # order, n_b = 1, in the refit on all data if that fit is identifiable and admissible
        late = ~active & self._active_inputs(first, g.n)
        if np.any(late):
            ext = ArxOrders(full.na, tuple(1 if lt else nb for lt, nb in zip(late, full.nb)), c.nk, c.intercept)
            try:
                fit = fit_arx(y[first:], g.u[first: g.n], ext, np.where(np.isfinite(y[first:]), w[first:], 0.0),
                              what="ARX refit with the inputs that began to vary")
            except RankDeficientError:
                return sel
            if self._admissible(fit):
                fit.extra.update(sel.model.extra)
                sel.model, sel.orders = fit, ext
        return sel

    def _max_pole_radius(self) -> float:
        """Largest admissible pole magnitude: exp(-step / max_time_constant) (1 without a bound)."""
        tau_h = self.config.max_time_constant_h
        if not math.isfinite(tau_h) or tau_h <= 0:
            return 1.0
        return math.exp(-self.step / (tau_h * 3600.0))

    def _admissible(self, m: ArxModel) -> bool:
        return m.is_stable(1.0 - self._max_pole_radius(), self.config.real_positive_poles) and \
            m.input_gains_admissible(self.config.max_input_gain_ratio)

    def _first_fit(self, t_s: float) -> None:
        try:
            models = self._select(t_s)
        except RankDeficientError as exc:
            self.message = f"calibration phase continues: {exc}"
            return
        self.models = models
        # CP gaps become "predicted" outputs (interpolated, or the new model's predictions)
        g = self.grid
        for j in range(len(self.component_names)):
            y, _ = self._training_outputs(j)
            g.y[: g.n, j] = y
        self.phase = PHASE_COMPENSATION
        self.t_last_update = t_s
        self.parameter_updates += 1
        self._resimulate_after(-1 if self.config.resimulate_history_on_update or
                               self.config.cp_gap_fill == "predict" else self._last_measured_index())
        summary = ", ".join(f"{n}: na={m.orders.na} nb={list(m.orders.nb)}" for n, m in models.items())
        self.message = (f"calibration phase ended after {(t_s - self.t0) / 3600:.2f} h, "
                        f"{self.probing_cycles} measurements; orders {summary}")
        self.events.append({"t_s": t_s, "event": "calibration_end",
                            "orders": {n: m.orders.to_state() for n, m in models.items()}})

    def _last_measured_index(self) -> int:
        g = self.grid
        any_m = np.any(g.measured[: g.n], axis=1)
        return int(np.flatnonzero(any_m)[-1]) if np.any(any_m) else 0

    def _update(self, t_s: float, why: str) -> None:
        """Parameter update by WLS (orders re-selected when they may grow or if configured)."""
        c = self.config
        g = self.grid
        regrow = self._nb_max_now() > self.nb_max_selected
        new_models: dict[str, ArxModel] = {}
        failures = []
        if regrow or c.reselect_orders_on_update:
            try:
                new_models = self._select(t_s, failures)
            except RankDeficientError as exc:
                failures.append(str(exc))
        # components without a (admissible) new selection: refit their current orders
        for j, name in enumerate(self.component_names):
            if name in new_models:
                continue
            old = self.models.get(name)
            if old is None:
                continue
            y, m = self._training_outputs(j)
            w = self._weights(t_s, m)
            w = np.where(np.isfinite(y), w, 0.0)
            try:
                fit = fit_arx(y, g.u[: g.n], old.orders, w, what=f"{name} update")
                fit.extra["validation_rms"] = old.extra.get("validation_rms", math.nan)
                if self._admissible(fit):
                    new_models[name] = fit
                else:
                    failures.append(f"{name}: the refit is unstable or has non-thermal poles")
                    new_models[name] = old
            except RankDeficientError as exc:
                failures.append(str(exc))
                new_models[name] = old
        if c.update_acceptance and why == "update interval":
            for j, name in enumerate(self.component_names):
                old, new = self.models.get(name), new_models.get(name)
                if old is None or new is None or new is old:
                    continue
                if self._predictor_error(new, j, t_s) > self._predictor_error(old, j, t_s):
                    failures.append(f"{name}: the new parameters predict the measured history worse")
                    new_models[name] = old
        self.models.update(new_models)
        self.t_last_update = t_s
        self.parameter_updates += 1
        self._resimulate_after(-1 if c.resimulate_history_on_update else self._last_measured_index())
        self.message = f"parameter update {self.parameter_updates} ({why})" + \
            (f"; kept old parameters where: {'; '.join(failures)}" if failures else "")
        self.events.append({"t_s": t_s, "event": "update", "why": why})

    def _predictor_error(self, model: ArxModel, j: int, t_s: float) -> float:
        """Weighted RMS of the TALC predictor's residuals at the measured samples of the
        history (between measurements the model runs on its own predictions)."""
        g = self.grid
        y, m = self._training_outputs(j)
        finite = np.flatnonzero(np.isfinite(y))
        if finite.size == 0:
            return math.inf
        start = max(int(finite[0]) + model.orders.max_lag, model.orders.max_lag, 1)
        if start >= g.n:
            return math.inf
        pred = model.simulate(g.u[: g.n], y, start, measured=m, y_measured=y)
        w = self._weights(t_s, m)
        sel = m.copy()
        sel[:start] = False
        sel &= np.isfinite(pred) & (w > 0)
        if not np.any(sel):
            return math.inf
        return float(np.sqrt(np.sum(w[sel] * (y[sel] - pred[sel]) ** 2) / np.sum(w[sel])))

    def _maybe_periodic_update(self, t_s: float) -> None:
        if self.phase != PHASE_COMPENSATION:
            return
        if self.t_last_update is None:  # pre-trained start: the update clock starts now
            self.t_last_update = t_s
            return
        if t_s - self.t_last_update >= self.config.update_interval_h * 3600.0:
            with single_thread_blas():
                self._update(t_s, "update interval")

    # ------------------------------------------------------------------ status
    def q_prod_pct(self, t_s: float) -> float:
        if self.t0 is None:
            return 100.0
        elapsed = t_s - self.t0
        if elapsed <= 0:
            return 100.0
        n = self.probing_cycles + self.failed_probing_cycles
        return min(100.0, max(0.0, q_prod(n, elapsed, self.config.probe_duration_s)))

    def status(self, t_s: float) -> ModelStatusData:
        unc = [self._uncertainty(n) for n in self.component_names] if self.models else []
        unc = [u for u in unc if math.isfinite(u)]
        return ModelStatusData(
            phase=self.phase, probing_cycles=self.probing_cycles,
            failed_probing_cycles=self.failed_probing_cycles, no_good_phases=self.no_good_phases,
            parameter_updates=self.parameter_updates,
            training_samples=int(self.grid.n) if self.grid is not None else 0,
            q_prod_pct=self.q_prod_pct(float(t_s)), next_probing_due_s=self.next_probe_due_s(),
            max_uncertainty=max(unc) if unc else math.nan,
            excluded_sensor_ids=list(self.held_inputs), message=self.message)

    # ------------------------------------------------------------------ persistence
    def to_state(self) -> dict:
        return {
            "kind": self.kind, "version": STATE_VERSION, "config": self.config.as_dict(),
            "input_names": list(self.input_names), "t0": self.t0, "t_last": self.t_last,
            "phase": self.phase, "models": {n: m.to_state() for n, m in self.models.items()},
            "grid": self.grid.to_state() if self.grid is not None else None,
            "input_ref": dict(self.input_ref), "input_last": dict(self.input_last),
            "counters": {"probing_cycles": self.probing_cycles,
                         "failed_probing_cycles": self.failed_probing_cycles,
                         "no_good_phases": self.no_good_phases,
                         "parameter_updates": self.parameter_updates},
            "ng_left": self.ng_left, "last_probe_t": self.last_probe_t,
            "t_last_update": self.t_last_update, "nb_max_selected": self.nb_max_selected,
            "out_of_sample": {n: list(v) for n, v in self.out_of_sample.items()},
            "message": self.message, "events": list(self.events),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "TalcModel":
        if state.get("kind") != cls.kind:
            raise ValueError(f"TALC state: 'kind' is {state.get('kind')!r}, expected 'talc'")
        if state.get("version") != STATE_VERSION:
            raise ValueError(f"TALC state: 'version' {state.get('version')!r} is not {STATE_VERSION}")
        cfg = dict(state["config"])
        cfg["input_names"] = list(state["input_names"])
        model = cls(TalcConfig.from_mapping(cfg))
        model.input_names = list(state["input_names"])
        grid = state["grid"]
        if model.input_names:
            model._init_grid()
        if grid is not None:
            model.grid = _Grid.from_state(grid, len(model.input_names), len(model.component_names))
        model.t0, model.t_last = state["t0"], state["t_last"]
        if state["phase"] not in (PHASE_CALIBRATION, PHASE_COMPENSATION, PHASE_NO_GOOD):
            raise ValueError(f"TALC state: 'phase' {state['phase']!r} is not a phase")
        model.phase = state["phase"]
        model.models = {n: ArxModel.from_state(d) for n, d in state["models"].items()}
        model.input_ref = {k: float(v) for k, v in state["input_ref"].items()}
        model.input_last = {k: float(v) for k, v in state["input_last"].items()}
        for k, v in state["counters"].items():
            setattr(model, k, int(v))
        model.ng_left = float(state["ng_left"])
        model.last_probe_t = state["last_probe_t"]
        model.t_last_update = state["t_last_update"]
        model.nb_max_selected = int(state["nb_max_selected"])
        model.out_of_sample = {n: [float(x) for x in v] for n, v in state["out_of_sample"].items()}
        model.message = state.get("message", "")
        model.events = list(state.get("events", []))
        return model

    @classmethod
    def from_pretrained(cls, state: Mapping[str, Any], config: Mapping[str, Any] | None = None
                        ) -> "TalcModel":
        """Start a new run in the compensation phase with the parameters of a trained model.

        ``config`` overrides the trained model's configuration (e.g. the Table 7.1 set).
        The history starts empty: inputs and errors are deltas from the new start.
        """
        trained = cls.from_state(state)
        if not trained.models:
            raise ValueError("pretrained model: it has no fitted parameters (still in calibration)")
        cfg = trained.config.as_dict()
        cfg.update(dict(config or {}))
        cfg["input_names"] = list(trained.input_names)
        model = cls(TalcConfig.from_mapping(cfg))
        model.models = {n: ArxModel.from_state(m.to_state()) for n, m in trained.models.items()}
        model.phase = PHASE_COMPENSATION
        model.nb_max_selected = trained.nb_max_selected
        model.message = "started from a pre-trained model (no calibration phase)"
        return model

