"""A prior from the machine type for the AGP: Gaussian processes identified on virtual experiments
of the NOMINAL lathe (other load programmes and seeds than the run), used as the prior mean of
the run's AGP.

:func:`build_agp_prior` samples the nominal recordings once per part cycle (simulation: the error
is known at every instant, no probing is charged), fits one ARD GP per component (its
hyper-parameters), drops the inputs whose ARD length scale ran to the bound (input selection),
and scores the GP on the held-out last recording. :class:`AgpPriorModel` is the AGP whose GPs
learn the RESIDUAL of the run's probes about the prior's mean: the prior compensates from the
first instant; the first ``check_s`` are probed at the calibration interval and, when these
probes agree with the prior (RMS residual <= ``agree_um``), the calibration phase ends there
(otherwise the thesis's calibration phase continues, on the residuals); recalibration and
control measurements are the AGP's, unchanged. :func:`agp_prior_from_state` turns another
machine's persisted AGP into a prior. docs/prior.md, section "AGP and characteristic diagrams".
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION, PHASE_COMPENSATION, register_prior_model
from talc_model.agp.model import AdaptiveGaussianProcess, AgpConfig
from talc_model.agp.gaussian_process import ArdGaussianProcess
from talc_model.prior.common import PRIOR_VERSION, PriorError, error_deltas, restore_with_prior
from talc_model.prior.integrity import training_check

#: an input whose ARD length scale reaches this fraction of the upper bound carries nothing
IRRELEVANT_FRACTION = 0.5
#: adaptation settings stored in the prior (overridable per run)
DEFAULT_ADAPTATION = {"check_s": 3600.0, "agree_um": None, "residual_std_um": None}


def agp_inputs(recording, config: AgpConfig) -> tuple[list[str], np.ndarray]:
    """The input rows the AGP sees online (fed through an :class:`AdaptiveGaussianProcess`, so
    NaN holding and ordering are the model's), one per recording row, as deltas from the first
    complete row: the errors are deltas from the run's start, and the absolute temperatures of
    a cold start differ between programmes (ambient), which the prior must not learn."""
    probe = AdaptiveGaussianProcess(config)
    sensors = {c[:-2]: np.asarray(recording.columns[c], float) for c in recording.names("sensor")}
    inputs = {c: np.asarray(recording.columns[c], float) for c in recording.names("input")}
    rows = []
    for k, t in enumerate(np.asarray(recording.time_s, float)):
        probe.update_inputs(float(t), {s: float(v[k]) for s, v in sensors.items()},
                            {s: float(v[k]) for s, v in inputs.items()})
        rows.append(probe.current_x.copy())
    x = np.asarray(rows)
    ok = np.all(np.isfinite(x), axis=1)
    return list(probe.input_names), x - (x[ok][0] if ok.any() else 0.0)


def training_set(recordings: Sequence[Any], config: AgpConfig, every_s: float):
    """[(input names, X, {component: y})] per recording, sampled every ``every_s``."""
    out = []
    for rec in recordings:
        names, x = agp_inputs(rec, config)
        t = np.asarray(rec.time_s, float)
        pick = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, every_s)).clip(0, t.size - 1))
        e = {c: error_deltas(rec, c)[pick] for c in config.components}
        ok = np.all(np.isfinite(x[pick]), axis=1) & np.all([np.isfinite(v) for v in e.values()], axis=0)
        out.append((names, x[pick][ok], {c: v[ok] for c, v in e.items()}))
    if len({tuple(n) for n, _, _ in out}) > 1:
        raise PriorError(f"agp prior: the training recordings have different inputs {[n for n, _, _ in out]}")
    return out


def _stack(parts, cols: Sequence[int], components: Sequence[str], max_points: int):
    x = np.vstack([p[1][:, cols] for p in parts])
    y = {c: np.concatenate([p[2][c] for p in parts]) for c in components}
    thin = np.unique(np.linspace(0, x.shape[0] - 1, min(max_points, x.shape[0])).round().astype(int))
    return x[thin], {c: v[thin] for c, v in y.items()}


def _gp(config: AgpConfig) -> ArdGaussianProcess:
    return ArdGaussianProcess(length_scale_bounds=tuple(config.length_scale_bounds),
                              noise_bounds=tuple(config.noise_bounds), n_restarts=config.n_restarts,
                              min_input_scale=config.min_input_scale, min_signal_std=0.0,
                              max_optimize_points=config.max_optimize_points, seed=config.seed)


def build_agp_prior(recordings: Sequence[Any], config: Mapping[str, Any] | AgpConfig, *, machine: str = "",
                    sources: Sequence[str] = (), every_s: float | None = None,
                    max_points: int = 400) -> dict[str, Any]:
    """The AGP prior from nominal recordings: GPs fitted on all of them (thinned evenly to
    ``max_points``); inputs whose length scale reaches half the upper bound on every component
    are dropped and the GPs refitted on the rest; the validation RMS is that of GPs fitted
    without the LAST recording, predicting it."""
    cfg = config if isinstance(config, AgpConfig) else AgpConfig.from_mapping(config)
    if len(recordings) < 2:
        raise PriorError(f"agp prior: needs >= 2 training recordings (one held out), got {len(recordings)}")
    every = float(every_s or cfg.calibration_probe_interval_s)
    parts = training_set(recordings, cfg, every)
    names = list(parts[0][0])
    cols = list(range(len(names)))
    x, y = _stack(parts, cols, cfg.components, max_points)
    if x.shape[0] < 10:
        raise PriorError(f"agp prior: only {x.shape[0]} training points (every_s {every})")
    gps = {c: _gp(cfg).fit(x, y[c], warm_start=False) for c in cfg.components}
    upper = cfg.length_scale_bounds[1] * IRRELEVANT_FRACTION
    keep = [i for i in cols if any(gp.length_scales[i] < upper for gp in gps.values())]
    if keep and len(keep) < len(cols):
        cols = keep
        x, y = _stack(parts, cols, cfg.components, max_points)
        gps = {c: _gp(cfg).fit(x, y[c], warm_start=False) for c in cfg.components}
    xv, yv = _stack(parts[:-1], cols, cfg.components, max_points)
    xh, yh = parts[-1][1][:, cols], parts[-1][2]
    held = {}
    for c in cfg.components:
        m, _ = _gp(cfg).fit(xv, yv[c], warm_start=False).predict(xh)
        held[c] = float(np.sqrt(np.mean((yh[c] - m) ** 2)))
    names = [names[i] for i in cols]
    state_cfg = asdict(cfg)
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "agp", "machine": machine,
            "sources": list(sources), "input_names": names,
            "sensors": [n for n in names if n not in cfg.machine_inputs],
            "machine_inputs": [n for n in names if n in cfg.machine_inputs],
            "gps": {c: gp.to_state() for c, gp in gps.items()},
            "length_scales": {c: gp.length_scales.tolist() for c, gp in gps.items()},
            "validation_rms": held, "training_points": int(x.shape[0]), "every_s": every,
            "training_check": training_check(cfg.components, xh, yh, "held-out training recording"),
            "agp_config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in state_cfg.items()},
            "adaptation": dict(DEFAULT_ADAPTATION)}


def agp_prior_from_state(state: Mapping[str, Any], machine: str = "") -> dict[str, Any]:
    """A prior from the persisted AGP state (kind ``agp``) of another machine: its fitted GPs
    and input names (its calibration and recalibrations were that machine's probes)."""
    trained = AdaptiveGaussianProcess.from_state(dict(state))
    if not all(gp.fitted for gp in trained.gps.values()) or not trained.input_names:
        raise PriorError("agp prior: the given AGP state has no fitted GPs (still in calibration)")
    cfg = trained.config
    names = list(trained.input_names)
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "agp", "machine": machine,
            "sources": ["persisted model state"], "input_names": names,
            "sensors": [n for n in names if n not in cfg.machine_inputs],
            "machine_inputs": [n for n in names if n in cfg.machine_inputs],
            "gps": {c: gp.to_state() for c, gp in trained.gps.items()},
            "length_scales": {c: gp.length_scales.tolist() for c, gp in trained.gps.items()},
            "validation_rms": {c: math.nan for c in trained.gps}, "training_points": len(trained.train_x),
            "agp_config": dict(state["config"]), "adaptation": dict(DEFAULT_ADAPTATION)}


@register_prior_model("agp")
class AgpPriorModel(AdaptiveGaussianProcess):
    """The AGP started from a prior: its GPs learn the residual about the prior's mean (module
    docstring). ``check_s``: length of the shortened calibration phase; ``agree_um``: the RMS
    residual of its probes below which the prior is trusted (default sigma_max / 2);
    ``residual_std_um``: prior std floor of the residual GP (default 1.25 sigma_max)."""

    kind = "agp"

    def __init__(self, config: Mapping[str, Any] | None = None, prior: Mapping[str, Any] | None = None,
                 check_s: float | None = None, agree_um: float | None = None,
                 residual_std_um: float | None = None):
        if not prior or prior.get("model_kind") != "agp":
            raise PriorError(f"agp prior: 'model_kind' is {(prior or {}).get('model_kind')!r}, expected 'agp'")
        cfg = dict(config or {})
        cfg["sensors"], cfg["machine_inputs"] = list(prior["sensors"]), list(prior["machine_inputs"])
        adapt = {**DEFAULT_ADAPTATION, **prior.get("adaptation", {})}
        res_std = residual_std_um if residual_std_um is not None else adapt["residual_std_um"]
        self.residual_std_um = None if res_std is None else float(res_std)
        self.x0: np.ndarray | None = None
        super().__init__(cfg)
        if self.residual_std_um is None:
            self.residual_std_um = 1.25 * self.config.sigma_max   # above sigma_max: a new state can still trigger a recalibration
        self.gps = {c: self._new_gp() for c in self.config.components}
        missing = [c for c in self.config.components if c not in prior["gps"]]
        if missing:
            raise PriorError(f"agp prior: no GP for component(s) {missing} (prior has {sorted(prior['gps'])})")
        self.prior = dict(prior)
        self.prior_gps = {c: ArdGaussianProcess.from_state(prior["gps"][c]) for c in self.config.components}
        self.check_s = float(check_s if check_s is not None else adapt["check_s"])
        agree = agree_um if agree_um is not None else adapt["agree_um"]
        self.agree_um = float(agree) if agree is not None else 0.5 * self.config.sigma_max
        if not (math.isfinite(self.check_s) and self.check_s >= 0 and math.isfinite(self.agree_um) and self.agree_um > 0):
            raise PriorError(f"agp prior: check_s {self.check_s!r} must be >= 0 and agree_um {self.agree_um!r} > 0")
        self.message = "prior: compensating with the machine type's GP, checking it with the first probes"
        self.hold.trust()
        self._prior_cache: tuple[int, dict[str, float]] | None = None

    def _new_gp(self) -> ArdGaussianProcess:
        """The residual GP: its prior std floor is ``residual_std_um`` (how far a unit may stray
        from the type's prior), not the thesis's fraction of the whole expected error."""
        gp = super()._new_gp()
        if self.residual_std_um is not None:
            gp.min_signal_std = self.residual_std_um
        return gp

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        """The AGP's inputs as deltas from the first complete row (as the prior was fitted)."""
        super().update_inputs(t_s, temperatures, machine_state)
        if self.x0 is None and np.all(np.isfinite(self.current_x)):
            self.x0 = self.current_x.copy()
        if self.x0 is not None:
            self.current_x = self.current_x - self.x0

    def prior_mean(self) -> dict[str, float]:
        """The prior's mean at the current inputs (NaN before any finite input)."""
        if self._prior_cache is not None and self._prior_cache[0] == self._cache_key:
            return self._prior_cache[1]
        if self.current_x is None or not np.all(np.isfinite(self.current_x)):
            mean = {c: math.nan for c in self.config.components}
        else:
            mean = {c: float(gp.predict(self.current_x[None, :])[0][0]) for c, gp in self.prior_gps.items()}
        self._prior_cache = (self._cache_key, mean)
        return mean

    def _predict_raw(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        values, stds = super()._predict_raw(t_s)
        pm = self.prior_mean()
        for c in self.config.components:
            values[c] += pm[c]
        for om in self.offset_models:
            values[om.component] += pm[om.base]
        return values, stds

    def _has_prediction(self) -> bool:
        """The prior's mean (plus the residual held in the shortened calibration) is a prediction."""
        return True

    def _learn(self, t_s: float, measured: Mapping[str, float],
               applied_compensation: Mapping[str, float]) -> None:
        pm = self.prior_mean() if self.current_x is not None else {}
        residual = {c: (float(v) - pm.get(c, math.nan) if c in pm else v) for c, v in measured.items()}
        super()._learn(t_s, residual, applied_compensation)

    def _maybe_finish_calibration(self, t_s: float) -> None:
        elapsed = t_s - (self.t_start if self.t_start is not None else t_s)
        n = len(self.train_x)
        if self.phase == PHASE_CALIBRATION and elapsed >= self.check_s and n >= 3:
            rms = max(math.sqrt(float(np.mean(np.square(self.train_y[c])))) for c in self.config.components)
            if rms <= self.agree_um:
                self._refit(optimize=True)
                self.phase = PHASE_COMPENSATION
                self.history = []
                self.message = (f"prior confirmed at t={t_s:.0f} s: {n} probes, RMS residual {rms:.2f} um "
                                f"<= {self.agree_um:.2f} um; predicting")
                return
        super()._maybe_finish_calibration(t_s)

    def to_state(self) -> dict:
        return {**super().to_state(), "prior": self.prior, "check_s": self.check_s, "agree_um": self.agree_um,
                "residual_std_um": self.residual_std_um, "x0": None if self.x0 is None else self.x0.tolist()}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "AgpPriorModel":
        if "prior" not in state:
            raise PriorError("agp prior: model state has no 'prior'")
        return restore_with_prior(cls(state["config"], state["prior"], state["check_s"], state["agree_um"],
                                      state["residual_std_um"]), AdaptiveGaussianProcess, state)



def agp_with_prior(config: Mapping[str, Any], prior: Mapping[str, Any], **kwargs) -> AgpPriorModel:
    """The run's AGP started from ``prior`` (from :func:`build_agp_prior` / ``thermal-comp prior``)."""
    return AgpPriorModel(config, prior, **kwargs)
