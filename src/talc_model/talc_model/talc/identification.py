"""The identification half of the TALC model: which grid rows train, their weights, when the
calibration phase may end, order selection, the first fit and the parameter updates.

:class:`TalcIdentification` is a mixin of :class:`talc_model.talc.model.TalcModel` (it reads and sets
the model's grid, configuration, models and counters); split out so that the streaming state
machine (talc.py) and the estimation read on their own. No rclpy here.
"""
from __future__ import annotations

import math

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION, PHASE_COMPENSATION
from talc_model.arx.model import ArxModel, ArxOrders, RankDeficientError, check_full_rank, fit_arx, regression_matrix
from talc_model.arx.observer import ObserverScoring, observer_predictions
from talc_model.arx.order_selection import select_orders
from thermal_comp_common.runtime.blas_threads import single_thread_blas


class TalcIdentification:
    """Estimation methods of :class:`~talc_model.talc.model.TalcModel` (see the module docstring)."""

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
        nb_max = self._nb_max_now()
        models = {}
        for j, name in enumerate(self.component_names):
            y, m = self._training_outputs(j)
            first = int(np.flatnonzero(np.isfinite(y))[0]) if np.any(np.isfinite(y)) else 0
            w = self._weights(t_s, m)
            try:
                sel = self._select_one(y, m, w, first, nb_max, self._scoring(name))
            except RankDeficientError as exc:
                if failures is None or name not in self.models:
                    raise
                failures.append(f"{name}: {exc}")
                continue
            models[name] = sel.model
        self.nb_max_selected = nb_max
        return models

    def _scoring(self, name: str) -> bool | ObserverScoring:
        """How order selection validates candidates of component ``name``: pure simulation in the
        calibration phase or without ``select_with_state_updates``, else with the state update
        the loop runs (the observer, or the thesis's replacement)."""
        c = self.config
        if self.phase == PHASE_CALIBRATION or not c.select_with_state_updates:
            return False
        if c.state_update == "observer":
            return ObserverScoring(self._probe_noise_var(name), max(1, c.uncertainty_window))
        return True

    def _select_one(self, y: np.ndarray, m: np.ndarray, w: np.ndarray, first: int, nb_max: int,
                    scoring: bool | ObserverScoring = False):
        """Order selection on the inputs that have varied on the training part of the split;
        the others get n_b = 0 in the returned model (see ``min_input_range``)."""
        c = self.config
        g = self.grid
        active = self._active_inputs(first, self._training_split(first))
        sel = select_orders(y[first:], g.u[first: g.n][:, active], (c.na_min, c.na_max), (c.nb_min, nb_max),
                            nk=c.nk, intercept=c.intercept, criterion=c.criterion,
                            train_fraction=c.train_fraction, weights=w[first:],
                            measured=m[first:], exhaustive_limit=c.order_search_exhaustive_limit,
                            state_updates=scoring,
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
            g.x[: g.n, j] = y     # the model's state: the measured (and interpolated) history
        # the observer starts from that history, each sample known to the probe noise
        last = self._last_measured_index()
        self.observer = {n: (last, self._probe_noise_var(n) * np.eye(m.orders.na)) for n, m in models.items()}
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
        history (between measurements the model runs on its own predictions; a measurement
        updates its state as the loop does: the observer, or the thesis's replacement)."""
        g = self.grid
        y, m = self._training_outputs(j)
        finite = np.flatnonzero(np.isfinite(y))
        if finite.size == 0:
            return math.inf
        start = max(int(finite[0]) + model.orders.max_lag, model.orders.max_lag, 1)
        if start >= g.n:
            return math.inf
        if self.config.state_update == "observer":
            name = self.component_names[j]
            pred = observer_predictions(model, g.u[: g.n], y, start, m, self._probe_noise_var(name),
                                        max(1, self.config.uncertainty_window), self._gain_scale(j))
        else:
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
