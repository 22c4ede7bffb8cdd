"""TALC, Thermal Adaptive Learning Control (Blaser thesis ch. 6): ARX models that learn online.

:class:`TalcModel` (kind ``"talc"``) behind the shared :class:`~talc_model.adaptive_model.AdaptiveModel`
protocol: a calibration phase (probe every cycle, no compensation), a compensation phase
(predictions on a 5-min grid; a measurement corrects the model's whole output state by the
gain of an observer, :mod:`talc_model.arx.observer`, or, as in the thesis, replaces the newest
predicted output) and
no-good phases (dense probing after a residual beyond the action-control limit, then a
parameter update). The state machine and prediction are here; the estimation is
:mod:`talc_model.talc.identification`, when to probe :mod:`talc_model.talc.probing_schedule`, the parameters :mod:`talc_model.talc.config`. The
thesis's phases in detail and every choice where it leaves a gap: docs/talc.md. No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from thermal_comp_common.metrics import q_prod

from talc_model.adaptive_model import (PHASE_CALIBRATION, PHASE_COMPENSATION, PHASE_NO_GOOD, ModelStatusData,
                                       prior_model_class, register_model)
from talc_model.arx.model import ArxModel
from talc_model.arx.observer import observer_update
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from talc_model.talc.config import PRESETS, TalcConfig, input_signal, parse_input  # noqa: F401 (PRESETS, parse_input: old import paths)
from talc_model.talc.grid import ModelGrid
from talc_model.talc.identification import TalcIdentification
from talc_model.talc.probing_schedule import TalcProbingSchedule
from talc_model.probing.hold_fallback import HoldFallback
from talc_model.type_inputs import held_input_labels, restore_soft_sensors, soft_sensors_for

STATE_VERSION = 1
#: a gap between two input updates longer than this many model steps is interpolated (``_advance``)
GAP_STEPS = 2.0


@register_model("talc")
class TalcModel(TalcProbingSchedule, TalcIdentification):
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
        self.grid: ModelGrid | None = None
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
        #: the switch-driven probing (TalcConfig.switch_probe_input): last value per signal, pending due time
        self.switch_last: dict[str, float] = {}
        self.switch_probe_due_s: float | None = None
        #: per-component multiples of the probe noise for the change-probing rule, derived from a
        #: prior's training programme (talc_model.probing.change_threshold); None = the config's one threshold
        self.change_thresholds: np.ndarray | None = None
        self.t_last_update: float | None = None
        self.nb_max_selected = c.nb_max            # max n_b used in the last order selection
        self.out_of_sample: dict[str, list[float]] = {n: [] for n in self.component_names}
        #: observer covariance per component: grid index of the last probe and its posterior
        self.observer: dict[str, tuple[int, np.ndarray]] = {}
        self.message = "calibration phase: waiting for the first measurement"
        self.events: list[dict] = []               # phase transitions and updates (for reports)
        self.soft_sensors = soft_sensors_for(c)    # the machine type's twin (type_model), or None
        #: per component: the model's prediction or its last probe (probing.hold_fallback)
        self.hold = HoldFallback(self.component_names, c.hold_fallback, horizon_s=c.post_cp_interval_h * 3600.0,
                                 noise_std={n: math.sqrt(self._probe_noise_var(n)) for n in self.component_names})
        if self.input_names:
            self._init_grid()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> "TalcModel":
        return cls(config)

    def _init_grid(self) -> None:
        self.grid = ModelGrid(len(self.input_names), len(self.component_names))

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
        signals = dict(machine_state)
        signals.update(temperatures)
        if self.soft_sensors is not None:
            signals.update(self.soft_sensors.update(t_s, temperatures, machine_state))
        new, held = {}, []
        for name in self.input_names:
            v = input_signal(name, signals)
            if math.isfinite(v):
                if name not in self.input_ref:
                    self.input_ref[name] = v
                new[name] = v - self.input_ref[name]
            else:
                held.append(name)
        # grid samples strictly before t_s lie between the last update and this one
        self._advance(t_s, inclusive=False, toward={**self.input_last, **new})
        self.input_last.update(new)
        self.held_inputs = held
        self._watch_switch(t_s, signals)
        self.t_last = t_s

    def _current_u(self) -> np.ndarray:
        return np.array([self.input_last.get(n, 0.0) for n in self.input_names])

    def _advance(self, t_s: float, inclusive: bool = True, toward: Mapping[str, float] | None = None) -> None:
        """Create grid samples up to t_s, predicting their outputs if a model exists.

        ``toward``: the inputs (deltas) that arrive at ``t_s``. Samples of a gap longer than
        GAP_STEPS model steps since the last update (a node resumed from a state saved an hour
        earlier, lost instants) take the inputs interpolated linearly between the two updates:
        held, the old inputs step at ``t_s`` and the ARX answers the step with its own lag
        (3.4 um off after a model restart in the demo graph). Shorter gaps (an instant shifted
        by a probing cycle) hold the last inputs, as the model was identified."""
        if self.t0 is None:
            self.t0 = t_s
        if self.grid is None:
            return
        eps = 1e-6 * self.step
        u0 = self._current_u()
        u1 = None if toward is None or self.t_last is None or t_s - self.t_last <= GAP_STEPS * self.step else \
            np.array([toward.get(n, 0.0) for n in self.input_names])
        while True:
            k = self.grid.n
            tk = self._t(k)
            if tk > t_s + eps or (not inclusive and tk > t_s - eps):
                break
            w = 0.0 if u1 is None else min(max((tk - self.t_last) / (t_s - self.t_last), 0.0), 1.0)
            self.grid.append(u0 if w == 0.0 else u0 + w * (u1 - u0))
            if self.phase != PHASE_CALIBRATION:
                self._predict_sample(k)

    def _predict_sample(self, k: int) -> None:
        """Predict the state of grid sample k; a measured sample keeps its measurement as the
        output and (re-)applies the state update to its prediction."""
        g = self.grid
        for j, name in enumerate(self.component_names):
            m = self.models.get(name)
            if g.measured[k, j]:
                if m is not None and self.config.state_update == "observer":
                    g.x[k, j] = self._predict_with(m, j, k)
                    self._observe(j, k, float(g.y[k, j]))
                else:
                    g.x[k, j] = g.y[k, j]
                continue
            if m is None:
                continue
            g.x[k, j] = g.y[k, j] = self._predict_with(m, j, k)

    def _predict_with(self, m: ArxModel, j: int, k: int) -> float:
        g = self.grid
        lag = m.orders.max_lag
        if k >= lag:
            y_hist = g.x[: k + 1, j]
            u_hist = g.u[: k + 1]
            kk = k
        else:  # before the start: outputs and input deltas were zero (steady reference state)
            pad = lag - k
            y_hist = np.concatenate([np.zeros(pad), g.x[: k + 1, j]])
            u_hist = np.vstack([np.zeros((pad, g.u.shape[1])), g.u[: k + 1]])
            kk = k + pad
        v = m.predict_one(y_hist, u_hist, kk)
        return v if math.isfinite(v) else 0.0

    def _resimulate_after(self, k: int) -> None:
        if k < 0:   # the whole history again: the observer restarts from the start's exact state
            self.observer = {}
        for kk in range(k + 1, self.grid.n):
            self._predict_sample(kk)

    # ------------------------------------------------------------------ state update
    def _probe_noise_var(self, name: str) -> float:
        c = self.config
        s = c.probe_noise_angular_um_per_m if name in c.angular_components else c.probe_noise_linear_um
        return s * s

    def _gain_scale(self, j: int) -> float:
        """Extra damping of the observer's gain for component j (1: none; see TalcPriorModel)."""
        return 1.0

    def _observe(self, j: int, k: int, total: float) -> None:
        """State update of component j by a measured total error at grid sample k, whose
        prediction is in ``grid.x[k, j]`` (docstring of :mod:`talc_model.arx.observer`)."""
        g = self.grid
        name = self.component_names[j]
        m = self.models[name]
        na = m.orders.na
        k_last, p = self.observer.get(name, (-1, np.zeros((na, na))))
        if p.shape != (na, na):          # the orders changed at an update: lags known to the probe noise
            p = self._probe_noise_var(name) * np.eye(na)
        innovation = total - float(g.x[k, j])
        # mean square of the recent innovations, this one included (covariance matching)
        recent = self.out_of_sample.get(name, [])[-(max(1, self.config.uncertainty_window) - 1):] \
            if self.config.uncertainty_window > 1 else []
        ms = float(np.mean(np.square(list(recent) + [innovation])))
        corr, p = observer_update(m.a, p, k - k_last, innovation, ms, self._probe_noise_var(name),
                                  self._gain_scale(j))
        for i, dx in enumerate(corr):
            if k - i < 0:
                break
            g.x[k - i, j] += dx
            if not g.measured[k - i, j]:
                g.y[k - i, j] = g.x[k - i, j]
        self.observer[name] = (k, p)

    # ------------------------------------------------------------------ prediction
    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        """The compensation: per component the model's prediction or, where it is not worth more
        than the last probe (or in the calibration phase), that probe (:attr:`hold`)."""
        values, stds = self._predict_raw(t_s)
        return self.hold.output(float(t_s), values, self.phase != PHASE_CALIBRATION), stds

    def _predict_raw(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
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
            v = self.grid.x[k, j]
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

    # ------------------------------------------------------------------ measurements
    def _limit(self, name: str) -> float:
        c = self.config
        return c.acl_angular_um_per_m if name in c.angular_components else c.acl_linear_um

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        t_s = float(t_s)
        self._advance(t_s)
        self.failed_probing_cycles += 1
        self._probed(t_s)
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
        observer = self.phase != PHASE_CALIBRATION and self.config.state_update == "observer"
        for j, name in enumerate(self.component_names):
            if name not in total:
                continue
            innovation = None
            if self.phase != PHASE_CALIBRATION and not g.measured[k, j] and math.isfinite(g.x[k, j]):
                innovation = total[name] - g.x[k, j]
            if observer and name in self.models and math.isfinite(g.x[k, j]):
                self._observe(j, k, total[name])      # before the innovation joins the window
            elif innovation is not None:              # the thesis's replacement (damped by _gain_scale)
                g.x[k, j] += self._gain_scale(j) * innovation
            else:
                g.x[k, j] = total[name]
            if innovation is not None:
                self.out_of_sample[name].append(innovation)
                del self.out_of_sample[name][:-max(1, self.config.uncertainty_window)]
            g.y[k, j] = total[name]
            g.measured[k, j] = True
        self.probing_cycles += 1
        self._probed(t_s)
        if self.phase != PHASE_CALIBRATION:
            self._resimulate_after(k)
        self.hold.observe(t_s, total)
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
            excluded_sensor_ids=list(self.held_inputs) + held_input_labels(self.soft_sensors),
            message=self.message + self.hold.note())

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
            "switch": {"last": dict(self.switch_last), "probe_due_s": self.switch_probe_due_s},
            "t_last_update": self.t_last_update, "nb_max_selected": self.nb_max_selected,
            "out_of_sample": {n: list(v) for n, v in self.out_of_sample.items()},
            "observer": {n: {"k": k, "p": p.tolist()} for n, (k, p) in self.observer.items()},
            "message": self.message, "events": list(self.events),
            "soft_sensors": self.soft_sensors.to_state() if self.soft_sensors is not None else None,
            "hold_fallback": self.hold.to_state(),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "TalcModel":
        if state.get("kind") != cls.kind:
            raise ValueError(f"TALC state: 'kind' is {state.get('kind')!r}, expected 'talc'")
        if state.get("version") != STATE_VERSION:
            raise ValueError(f"TALC state: 'version' {state.get('version')!r} is not {STATE_VERSION}")
        if cls is TalcModel and state.get("prior") is not None:   # a run started from a prior resumes with it
            return prior_model_class(cls.kind).from_state(state)
        cfg = dict(state["config"])
        cfg["input_names"] = list(state["input_names"])
        model = cls(TalcConfig.from_mapping(cfg))
        model.input_names = list(state["input_names"])
        grid = state["grid"]
        if model.input_names:
            model._init_grid()
        if grid is not None:
            model.grid = ModelGrid.from_state(grid, len(model.input_names), len(model.component_names))
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
        switch = state.get("switch") or {}          # states saved before the switch probing: none
        last = switch.get("last")                   # one float in states of a single switch signal
        model.switch_last = dict(last) if isinstance(last, Mapping) else \
            ({model.config.switch_probe_names[0]: float(last)} if last is not None and model.config.switch_probe_names
             else {})
        model.switch_probe_due_s = switch.get("probe_due_s")
        model.t_last_update = state["t_last_update"]
        model.nb_max_selected = int(state["nb_max_selected"])
        model.out_of_sample = {n: [float(x) for x in v] for n, v in state["out_of_sample"].items()}
        model.observer = {n: (int(d["k"]), np.asarray(d["p"], float).reshape(len(d["p"]), len(d["p"])))
                          for n, d in (state.get("observer") or {}).items()}
        model.message = state.get("message", "") + restore_soft_sensors(model.soft_sensors, state)
        model.events = list(state.get("events", []))
        model.hold = HoldFallback.from_state(state.get("hold_fallback"), model.component_names,
                                             model.config.hold_fallback, model.config.post_cp_interval_h * 3600.0,
                                             {n: math.sqrt(model._probe_noise_var(n)) for n in model.component_names})
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
        model.hold.trust()
        return model
