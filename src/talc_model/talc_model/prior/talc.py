"""A prior from the machine type for TALC: ARX models identified on virtual experiments of the
NOMINAL machine (other load programmes and seeds than the run), adapted online with the probes.

:func:`build_talc_prior` fits one ARX model per component on recordings of the nominal twin
(simulation: the error is known at every instant, no probing is charged) and scores the order
candidates by simulation on a held-out recording. :class:`TalcPriorModel` is TALC started from
it: the prior's models compensate from the first instant; the first ``check_h`` hours are
probed at the calibration-phase interval (the shortened calibration phase: if the first probes
disagree with the prior by more than the action-control limit the unchanged no-good logic takes
over); every parameter update is a WLS regularised towards the prior (the prior counts as
``prior_samples`` samples of its own training data). A prior may also be the persisted state
of another machine's TALC model (:func:`prior_from_state`). docs/prior.md. No rclpy here.
"""
from __future__ import annotations

import dataclasses
import json
import math
import pathlib
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import PHASE_COMPENSATION, register_prior_model
from talc_model.arx.model import ArxModel, ArxOrders, RankDeficientError, regression_matrix, solve_wls
from talc_model.talc.model import TalcModel
from talc_model.talc.config import TalcConfig
from talc_model.prior.common import PRIOR_VERSION, PriorError
from talc_model.prior.integrity import check_talc_models, stamped, training_check, verify_file
from talc_model.type_inputs import twin_signal_names

#: ridge added to the prior's normalised Gram matrix (fraction of its mean diagonal)
RIDGE = 1e-2


def grid_from_recording(recording, config: TalcConfig) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """TALC's input grid (built by a :class:`TalcModel` fed the recording's inputs, so the inputs
    are exactly what the model sees online) and the true errors on that grid, relative to the
    first row (the run's errors are deltas from its start too)."""
    model = TalcModel(config)
    t = np.asarray(recording.time_s, float)
    sensors = {c[:-2]: np.asarray(recording.columns[c], float) for c in recording.names("sensor")}
    inputs = {c: np.asarray(recording.columns[c], float) for c in recording.names("input")}
    for k in range(t.size):
        model.update_inputs(float(t[k]), {s: float(v[k]) for s, v in sensors.items()},
                            {s: float(v[k]) for s, v in inputs.items()})
    model._advance(float(t[-1]))
    g = model.grid
    tg = model.t0 + np.arange(g.n) * model.step
    errors = {}
    for c in config.component_names:
        col = c if c in recording.columns else f"{c}_um"
        if col not in recording.columns:
            raise PriorError(f"prior: component {c!r} has no error column in the training recording")
        e = np.asarray(recording.columns[col], float)
        ok = np.isfinite(e)
        e0 = e[ok][0] if ok.any() else 0.0
        errors[c] = np.interp(tg, t[ok], e[ok] - e0)
    return g.u[: g.n].copy(), errors


def _stack(grids: Sequence[tuple[np.ndarray, np.ndarray]], orders: ArxOrders):
    """Regression rows of several recordings, each built on its own (no lag crosses a seam)."""
    phis, targets = [], []
    for u, y in grids:
        phi, target, _ = regression_matrix(y, u, orders)
        ok = np.isfinite(target) & np.all(np.isfinite(phi), axis=1)
        phis.append(phi[ok])
        targets.append(target[ok])
    return np.vstack(phis), np.concatenate(targets)


def _sim_rms(model: ArxModel, u: np.ndarray, y: np.ndarray) -> float:
    lag = model.orders.max_lag
    pred = model.simulate(u, np.zeros(lag), lag)
    r = (y - pred)[lag:]
    return float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2)))


def _fit_component(train, held_out, config: TalcConfig, n_inputs: int, max_radius: float,
                   na_max: int, nb_max: int):
    """Best (by simulation RMS on ``held_out``) admissible orders, refitted on all data.

    An input that never varies in ``train`` (e.g. the MWF flag when only dry programmes train)
    gets n_b = 0 in the search and n_b = 1 in the refit on all data if it varies there (as
    TALC's ``min_input_range``): otherwise every candidate would be rank-deficient."""
    def varies(grids):
        return np.array([any(np.ptp(u[:, i]) > config.min_input_range for u, _ in grids)
                         for i in range(n_inputs)], bool)
    active, active_all = varies(train), varies(list(train) + list(held_out))
    best = None
    for na in range(1, na_max + 1):
        for nb in range(1, nb_max + 1):
            orders = ArxOrders(na, tuple(nb if a else 0 for a in active), config.nk, config.intercept)
            try:
                phi, target = _stack(train, orders)
                theta = solve_wls(phi, target, what="prior regression matrix")
            except RankDeficientError:
                continue
            m = ArxModel(orders, theta)
            if not m.is_stable(1.0 - max_radius):
                continue
            score = max(_sim_rms(m, u, y) for u, y in held_out)
            if math.isfinite(score) and (best is None or score < best[0]):
                best = (score, orders)
    if best is None:
        raise PriorError("prior: no stable ARX candidate fits the training recordings")
    orders = best[1]
    if np.any(active_all & ~active):
        orders = ArxOrders(orders.na, tuple(1 if (aa and not a) else nb for a, aa, nb in
                                            zip(active, active_all, orders.nb)), config.nk, config.intercept)
        best = (best[0], orders)
    phi, target = _stack(list(train) + list(held_out), best[1])
    theta = solve_wls(phi, target, what="prior regression matrix")
    res = target - phi @ theta
    m = ArxModel(best[1], theta, float(np.std(res)), int(phi.shape[0]),
                 {"validation_rms": best[0], "prior": True})
    gram = (phi.T @ phi) / phi.shape[0]
    return m, gram


def with_discrepancy_pole(model: ArxModel, pole: float) -> ArxModel:
    """``model`` with A(q) and every B(q) multiplied by (1 - pole q^-1): the same input-output
    map (identical predictions from a consistent start), one pole more. A probe's correction of
    the state then persists with that pole instead of the model's own: a model fitted exactly
    on the nominal twin's soft sensors has a pole near 0 (the error map is static), which would
    forget a probe within one step; the unit's discrepancy from its type is what the probes
    measure, and it changes slowly (docs/talc.md)."""
    o = model.orders
    factor = np.array([1.0, -float(pole)])
    a = np.convolve(np.concatenate(([1.0], model.a)), factor)[1:]
    bs = [np.convolve(b, factor) if b.size else b for b in model.b]
    orders = ArxOrders(o.na + 1, tuple(b.size for b in bs), o.nk, o.intercept)
    theta = np.concatenate([a] + bs + ([np.array([model.c * (1.0 - pole)])] if o.intercept else []))
    return ArxModel(orders, theta, model.residual_std, model.n_fit_samples,
                    {**model.extra, "discrepancy_pole": float(pole)})


def build_talc_prior(recordings: Sequence[Any], config: Mapping[str, Any] | TalcConfig,
                     machine: str = "", sources: Sequence[str] = (), na_max: int = 1,
                     nb_max: int = 8) -> dict[str, Any]:
    """The prior (a JSON-serialisable dict) from training recordings of the nominal type.

    The last recording is held out to choose the orders n_a <= ``na_max``, n_b <= ``nb_max``
    (simulation RMS), then all are fitted. n_a = 1 by default: with the thesis's state update
    (a probe replaces one predicted output) n_a > 1 diverged; with TALC's observer it is stable,
    but an n_a <= 3 prior was better on two of the four load cases and worse on two (docs/talc.md).
    """
    for name, v in (("na_max", na_max), ("nb_max", nb_max)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise PriorError(f"prior: {name} {v!r} must be an integer >= 1")
    if len(recordings) < 2:
        raise PriorError(f"prior: {len(recordings)} training recording(s); need at least 2 "
                         "(one is held out to choose the orders)")
    cfg = config if isinstance(config, TalcConfig) else TalcConfig.from_mapping(config)
    if cfg.type_input_names:          # the inputs of runs started from a prior of the type
        cfg = dataclasses.replace(cfg, input_names=list(cfg.type_input_names))
    if not cfg.input_names:
        raise PriorError("prior: the TALC configuration names no 'input_names'")
    grids = [grid_from_recording(r, cfg) for r in recordings]
    probe = TalcModel(cfg)
    max_radius = probe._max_pole_radius()
    models, grams = {}, {}
    # soft sensors of the machine type as inputs: the fit is the (static) error map, pole near 0;
    # the discrepancy pole makes a probe's correction persist (with_discrepancy_pole)
    pole = math.exp(-cfg.model_step_s / (cfg.type_discrepancy_tau_h * 3600.0)) \
        if twin_signal_names(cfg.input_names) else None
    for c in cfg.component_names:
        data = [(u, e[c]) for u, e in grids]
        models[c], grams[c] = _fit_component(data[:-1], data[-1:], cfg, len(cfg.input_names), max_radius,
                                                   na_max, nb_max)
        if pole is not None:
            models[c] = with_discrepancy_pole(models[c], pole)
            phi, _ = _stack(data, models[c].orders)
            grams[c] = (phi.T @ phi) / phi.shape[0]
    probe.models = models
    probe.phase = PHASE_COMPENSATION
    # adaptation defaults (docs/prior.md). state_gain 1: TALC's observer weighs each probe by its
    # noise (1.2 um/m angular, Table 5.4) itself; the fixed 0.5 on angular components of the
    # replacement update over-damps it (docs/talc.md)
    adaptation = {"prior_samples": 200.0, "check_h": 1.0,
                  "state_gain": {c: 1.0 for c in cfg.component_names}}
    held_u, held_errors = grids[-1]
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "talc", "machine": machine,
            "sources": list(sources), "talc_state": probe.to_state(), "adaptation": adaptation,
            "gram": {c: g.tolist() for c, g in grams.items()},
            "validation_rms": {c: m.extra["validation_rms"] for c, m in models.items()},
            "training_check": training_check(models, held_u, held_errors,
                                             list(sources)[-1] if sources else "held-out recording")}


def prior_from_state(state: Mapping[str, Any], machine: str = "") -> dict[str, Any]:
    """A prior from the persisted TALC state of another machine (its fitted models; the
    regularisation weight uses the identity scaled by each model's fit size)."""
    trained = TalcModel.from_state(state)
    if not trained.models:
        raise PriorError("prior: the given TALC state has no fitted models (still in calibration)")
    grams = {c: np.eye(m.orders.n_params).tolist() for c, m in trained.models.items()}
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "talc", "machine": machine,
            "sources": ["persisted model state"], "talc_state": dict(state), "gram": grams,
            "validation_rms": {c: m.extra.get("validation_rms", math.nan) for c, m in trained.models.items()}}


def save_prior(path: str | pathlib.Path, prior: Mapping[str, Any]) -> pathlib.Path:
    """Write ``prior`` (any model kind) with its identity block and content hash."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stamped(prior), allow_nan=True) + "\n")
    return path


def load_prior(path: str | pathlib.Path) -> dict[str, Any]:
    """A prior file (from ``thermal-comp prior``; its hash and identity checked) or a persisted
    TALC model state."""
    try:
        data = json.loads(pathlib.Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise PriorError(f"prior {str(path)!r}: cannot read it ({exc})") from None
    if isinstance(data, dict) and data.get("kind") == "talc":
        return prior_from_state(data)
    if not isinstance(data, dict) or data.get("kind") != "prior":
        raise PriorError(f"prior {str(path)!r}: 'kind' is {data.get('kind') if isinstance(data, dict) else None!r}, "
                         "expected 'prior' (or a TALC model state)")
    if data.get("version") != PRIOR_VERSION:
        raise PriorError(f"prior {str(path)!r}: 'version' {data.get('version')!r} is not {PRIOR_VERSION} "
                         "(a prior without identity and content hash): rebuild it with thermal-comp prior")
    verify_file(repr(str(path)), data)
    return data


@register_prior_model("talc")
class TalcPriorModel(TalcModel):
    """TALC started from a prior (module docstring); same protocol and kind as TALC."""

    def __init__(self, config=None, prior: Mapping[str, Any] | None = None, prior_samples: float = 200.0,
                 check_h: float = 1.0, state_gain: float | Mapping[str, float] = 1.0):
        super().__init__(config)
        gains = dict(state_gain) if isinstance(state_gain, Mapping) else \
            {c: state_gain for c in self.component_names}
        for c, v in gains.items():
            if c not in self.component_names or not (isinstance(v, (int, float)) and 0 < v <= 1):
                raise PriorError(f"state_gain[{c!r}]: {v!r} must be in (0, 1] for a component of the model")
        self.state_gain = {c: float(gains.get(c, 1.0)) for c in self.component_names}
        self._gain = np.array([self.state_gain[c] for c in self.component_names])
        if not (math.isfinite(prior_samples) and prior_samples >= 0):
            raise PriorError(f"prior_samples: {prior_samples!r} must be a finite number >= 0")
        if not (math.isfinite(check_h) and check_h >= 0):
            raise PriorError(f"prior check_h: {check_h!r} must be a finite number >= 0")
        self.prior = dict(prior) if prior is not None else None
        self.prior_samples = float(prior_samples)
        self.check_h = float(check_h)
        self.prior_models: dict[str, ArxModel] = {}
        self.prior_gram: dict[str, np.ndarray] = {}
        if self.prior is not None:
            self._install_prior()
            self.hold.trust()

    def _install_prior(self) -> None:
        trained = TalcModel.from_state(self.prior["talc_state"])
        if list(trained.input_names) != list(self.input_names):
            raise PriorError(f"prior: inputs {trained.input_names} differ from the model's {self.input_names}")
        missing = sorted(set(self.component_names) - set(trained.models))
        if missing:
            raise PriorError(f"prior: no model for component(s) {missing}")
        self.prior_models = {c: trained.models[c] for c in self.component_names}
        check_talc_models(self.prior_models, self.prior.get("training_check"))
        # the Gram matrix of collinear regressors is near singular: a small ridge (relative to
        # its mean diagonal) keeps the prior's hold on every direction of the parameters
        self.prior_gram = {}
        for c in self.component_names:
            g = np.asarray(self.prior["gram"][c], float)
            self.prior_gram[c] = g + RIDGE * np.mean(np.diag(g)) * np.eye(g.shape[0])
        self.models = {c: ArxModel.from_state(m.to_state()) for c, m in self.prior_models.items()}
        self.phase = PHASE_COMPENSATION
        self.message = f"compensating with the prior of {self.prior.get('machine') or 'the machine type'}"

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> "TalcPriorModel":
        return cls(config)

    def _in_check(self) -> bool:
        return self.t0 is not None and self.last_probe_t is not None and \
            self.last_probe_t - self.t0 < self.check_h * 3600.0

    def _check_end_s(self) -> float:
        return self.t0 + self.check_h * 3600.0

    def _interval_s(self) -> float:
        if self.phase == PHASE_COMPENSATION and self._in_check():
            return self.config.cp_interval_s      # the shortened calibration phase
        return super()._interval_s()

    def _gain_scale(self, j: int) -> float:
        """``state_gain``: a fixed damping of the observer's gain (1 = the observer alone)."""
        return float(self._gain[j])

    def _update(self, t_s: float, why: str) -> None:
        """WLS regularised towards the prior; without a prior, TALC's own update."""
        if not self.prior_models:
            return super()._update(t_s, why)
        g = self.grid
        kept = []
        for j, c in enumerate(self.component_names):
            old, p = self.models[c], self.prior_models[c]
            y, m = self._training_outputs(j)
            w = np.where(np.isfinite(y), self._weights(t_s, m), 0.0)
            phi, target, rows = regression_matrix(y, g.u[: g.n], p.orders)
            w = w[rows]
            ok = np.isfinite(target) & np.all(np.isfinite(phi), axis=1) & (w > 0)
            a = (phi[ok] * w[ok, None]).T @ phi[ok] + self.prior_samples * self.prior_gram[c]
            b = (phi[ok] * w[ok, None]).T @ target[ok] + self.prior_samples * self.prior_gram[c] @ p.theta
            try:
                theta = np.linalg.solve(a, b)
            except np.linalg.LinAlgError:
                kept.append(f"{c}: singular")
                continue
            new = ArxModel(p.orders, theta, old.residual_std, int(ok.sum()), dict(old.extra))
            if not self._admissible(new):
                kept.append(f"{c}: not admissible")
                continue
            if self.config.update_acceptance and why == "update interval" and \
                    self._predictor_error(new, j, t_s) > self._predictor_error(old, j, t_s):
                kept.append(f"{c}: predicts the history worse")
                continue
            self.models[c] = new
        self.t_last_update = t_s
        self.parameter_updates += 1
        self._resimulate_after(-1 if self.config.resimulate_history_on_update else self._last_measured_index())
        self.message = f"parameter update {self.parameter_updates} ({why}, towards the prior)" + \
            (f"; kept old parameters where {'; '.join(kept)}" if kept else "")
        self.events.append({"t_s": t_s, "event": "update", "why": why})

    def to_state(self) -> dict:
        state = super().to_state()
        state["prior"] = self.prior
        state["prior_samples"] = self.prior_samples
        state["check_h"] = self.check_h
        state["state_gain"] = self.state_gain
        return state

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "TalcPriorModel":
        base = TalcModel.from_state({k: v for k, v in state.items() if k != "prior"})
        model = cls(base.config, None, float(state.get("prior_samples", 200.0)), float(state.get("check_h", 1.0)),
                    state.get("state_gain", 1.0))
        model.__dict__.update({k: v for k, v in base.__dict__.items() if k != "config"})
        if state.get("prior") is not None:
            model.prior = dict(state["prior"])
            models = model.models
            model._install_prior()
            model.models, model.phase, model.message = models, base.phase, base.message
        return model


def talc_with_prior(config: Mapping[str, Any], prior: Mapping[str, Any], **kwargs) -> TalcPriorModel:
    """TALC with ``prior``; the model's ``input_names`` default to the prior's (and are the
    prior's when they are the configuration's ``type_input_names``: the type's inputs of a run
    started from its prior), the adaptation settings (prior_samples, check_h, state_gain) to
    the prior's ``adaptation`` mapping."""
    cfg = dict(config)
    inputs = list(prior["talc_state"]["input_names"])
    if list(cfg.get("type_input_names") or []) == inputs:
        cfg["input_names"] = inputs
    cfg.setdefault("input_names", inputs)
    settings = dict(prior.get("adaptation") or {})
    settings.update(kwargs)
    return TalcPriorModel(cfg, prior, **settings)


def training_labels(items: Iterable[tuple[str, int]]) -> list[str]:
    """``["scenario seed N", ...]`` for the prior's ``sources``."""
    return [f"{s} seed {n}" for s, n in items]
