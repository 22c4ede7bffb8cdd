"""A characteristic-diagram prior from the machine type, and the CD model started from it.

``build_cd_prior`` fits one CD per error component on virtual experiments of the NOMINAL type
(other load programmes and seeds than the run; ``thermal-comp prior --model cd``): the
candidate inputs are exactly the CD model's online ones (every temperature as a delta from the
run's first row, its low-passes and gradient, and, with :data:`PRIOR_SOFT_SENSORS`, every soft
sensor of the type: its nominal twin stepped from the machine inputs), chosen by the forward
heuristic scored on the LAST training recording held out (a prior must generalise to an unseen
programme), then fitted on all recordings. ``CdPriorModel`` (kind ``cd``) compensates with those
diagrams from the first instant, probes at the calibration interval for ``check_s`` and then
every ``update_probe_interval_s`` (or, opt-in, at the longest interval its measured change gain
allows: :func:`interval_from_gain`), and predicts the last probe plus the diagrams' change since
it times that gain.
:func:`cd_prior_from_state` turns another machine's persisted CD model into a prior. No rclpy
here. docs/prior.md, docs/agp_cd.md.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict
from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import PHASE_COMPENSATION, register_prior_model
from talc_model.cd.input_selection import forward_selection
from talc_model.cd.model import CdConfig, CharacteristicDiagramModel, extrapolated_axes
from talc_model.cd.diagram import CharacteristicDiagram
from talc_model.prior.common import PRIOR_VERSION, PriorError, error_deltas, restore_with_prior
from talc_model.prior.integrity import training_check
from talc_model.type_inputs import load_soft_sensors
from talc_model.probing.uncertainty_weighted_hold import change_gain
from thermal_comp_common.probe_and_hold import table_5_4_noise

#: adaptation settings stored in the prior (the run's configuration overrides the CD-model keys):
#: the prediction is the last probe plus the diagrams' change since it, weighted by the measured
#: gain over the last ``gain_window`` probe pairs (the prior's held-out gain before ``min_pairs``);
#: ``check_s`` 8 h at the calibration interval (30 min), the probes of the CD model's own calibration;
#: ``load_case_updates`` off: refitting the diagrams to the unit's probes made the anchored
#: prediction worse (12 h of talc-178h-dry, unit #1: P99_lin first 8 h 1.29 against 0.89 um
#: without, whole 12 h 3.81 against 2.48 um; docs/prior.md); ``interval_by_gain`` (off): after the
#: check the interval of :func:`interval_from_gain`; unbounded it beat probe-and-hold on 7 of 7 48-h
#: runs but at Q_prod 94.7-96.6 %; held at Q_prod >= 97 % (``min_q_prod_pct``) on 4 of 7 against 6 of 7
#: for the fixed 4 h (docs/prior.md), hence off; ``probe_noise`` (std per component, default
#: Table 5.4) is that rule's noise floor; ``min_q_prod_pct``: the rule never probes sooner than keeps
#: the run's Q_prod (probing time over the time since the start) at or above it once the next
#: probing is done (97 %, the thesis's production share)
DEFAULT_ADAPTATION = {"check_s": 8 * 3600.0, "update_batch": 1, "update_rmse_floor": 0.5, "gain_window": 12,
                      "min_pairs": 2, "load_case_updates": False, "interval_by_gain": False,
                      "min_q_prod_pct": 97.0}
#: lags (h) at which the prior keeps the held-out change statistics that choose the post-check
#: probing interval (:func:`interval_from_gain`); the longest is the CD model's update interval
CHANGE_LAGS_H = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
#: the prior's default low-pass time constants (s): the forward heuristic picks among them on the
#: held-out programme, which estimates the structure's lag per component
PRIOR_LOWPASS_S = (3600.0, 7200.0, 14400.0, 28800.0)
#: the CD structure is the prior's: these run-configuration keys are taken from it
STRUCTURE_KEYS = ("sensors", "use_gradients", "gradient_window_s", "lowpass_time_constants_s", "type_model",
                  "type_inputs", "extrapolate_type_inputs", "max_inputs", "n_intervals", "smoothing")
#: the prior's candidates include every soft sensor of the machine type (``type_model``: the
#: prior's machine unless the configuration names one) unless the configuration sets ``type_inputs``
PRIOR_SOFT_SENSORS = True


def cd_inputs(recording, config: CdConfig) -> tuple[list[str], list[str], np.ndarray]:
    """(sensors, candidate names, rows): the candidate inputs the CD model sees online, one row
    per recording row (fed through a :class:`CharacteristicDiagramModel`, so NaN holding and
    the gradient window are the model's), temperatures as deltas from the first complete row."""
    probe = CharacteristicDiagramModel(asdict(config))
    sensors = {c[:-2]: np.asarray(recording.columns[c], float) for c in recording.names("sensor")}
    inputs = {c: np.asarray(recording.columns[c], float) for c in recording.names("input")}
    rows = []
    for k, t in enumerate(np.asarray(recording.time_s, float)):
        probe.update_inputs(float(t), {s: float(v[k]) for s, v in sensors.items()},
                            {s: float(v[k]) for s, v in inputs.items()})
        rows.append(probe.current.copy())
    x = np.asarray(rows)
    n = probe.level_columns
    ok = np.all(np.isfinite(x), axis=1)
    if ok.any():
        x[:, :n] -= x[ok][0, :n]
    return list(probe.sensor_names), probe.candidate_names, x


def prior_config(config: Mapping[str, Any] | None, machine: str) -> dict[str, Any]:
    """The CD configuration a prior is built with: the prior's low-pass time constants and, with
    ``PRIOR_SOFT_SENSORS``, every soft sensor of the type (``type_model``, default ``machine``) as
    candidates unless ``config`` sets them (``type_inputs: []``: none); with soft sensors the
    diagrams extrapolate along them (``extrapolate_type_inputs``, unless set)."""
    cfg = {"lowpass_time_constants_s": list(PRIOR_LOWPASS_S), **dict(config or {})}
    if PRIOR_SOFT_SENSORS and "type_inputs" not in cfg:
        cfg["type_model"] = cfg.get("type_model") or machine
        if not cfg["type_model"]:
            raise PriorError("cd prior: no machine type for the soft sensors: give 'machine', 'type_model' in "
                             "the configuration, or 'type_inputs: []'")
        try:
            cfg["type_inputs"] = load_soft_sensors(cfg["type_model"], [], "cd prior", "'type_inputs'").names
        except ValueError as exc:
            raise PriorError(f"{exc} (give 'type_model' in the configuration, or 'type_inputs: []')") from None
    if cfg.get("type_inputs"):
        cfg.setdefault("extrapolate_type_inputs", True)
    return cfg


def _training_parts(recordings: Sequence[Any], cfg: CdConfig, every_s: float):
    parts, names = [], None
    for rec in recordings:
        sensors, cand, x = cd_inputs(rec, cfg)
        if names is not None and cand != names:
            raise PriorError(f"cd prior: the training recordings have different inputs ({names} vs {cand})")
        names = cand
        t = np.asarray(rec.time_s, float)
        pick = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, every_s)).clip(0, t.size - 1))
        e = {c: error_deltas(rec, c)[pick] for c in cfg.components}
        ok = np.all(np.isfinite(x[pick]), axis=1) & np.all([np.isfinite(v) for v in e.values()], axis=0)
        parts.append((sensors, x[pick][ok], {c: v[ok] for c, v in e.items()}))
    return parts, names


def held_out_change_gain(cd: CharacteristicDiagram, x: np.ndarray, y: np.ndarray, lag: int) -> float:
    """:func:`change_gain` of ``cd`` (fitted without the held-out programme) on the held-out
    rows ``x``, ``y``: changes over ``lag`` rows (the check phase's probe interval)."""
    f = cd.predict(x)
    return change_gain(y[lag:] - y[:-lag], f[lag:] - f[:-lag]) if y.size > lag else 1.0


def held_out_change_stats(cd: CharacteristicDiagram, x: np.ndarray, y: np.ndarray, every_s: float,
                          lags_h: Sequence[float] = CHANGE_LAGS_H) -> dict[str, list[float]]:
    """Second moments of the measured (dy) and predicted (dp) changes of ``cd`` (fitted without the
    held-out programme) on the held-out rows, per lag: mean dy^2, dy dp and dp^2. With a gain g the
    expected squared error of "last probe + g x predicted change" after a lag L is
    yy(L) - 2 g yp(L) + g^2 pp(L) (:func:`interval_from_gain`)."""
    f = cd.predict(x)
    out: dict[str, list[float]] = {"lags_h": [], "yy": [], "yp": [], "pp": []}
    for lag_h in lags_h:
        lag = max(1, int(round(lag_h * 3600.0 / every_s)))
        if y.size <= lag:
            continue
        dy, dp = y[lag:] - y[:-lag], f[lag:] - f[:-lag]
        out["lags_h"].append(float(lag_h))
        for key, v in (("yy", dy * dy), ("yp", dy * dp), ("pp", dp * dp)):
            out[key].append(float(np.mean(v)))
    return out


def interval_from_gain(stats: Mapping[str, Mapping[str, Sequence[float]]], gains: Mapping[str, float],
                       check_h: float, max_h: float, noise: Mapping[str, float] | None = None) -> float:
    """The post-check probing interval (h): the longest held-out lag L <= ``max_h`` at which, for
    every component, the expected squared error of the anchored prediction with the measured gain
    g, yy(L) - 2 g yp(L) + g^2 pp(L), is no larger than that of holding a probe for the check
    interval, yy(check_h): the model probes as seldom as it can while staying as accurate as the
    check phase's probe-and-hold, or than the probe's own noise variance ``noise``^2 (std per
    component) where that is larger: a drift below the probe noise is not what probing more often
    could resolve. A gain of 0 gives ``check_h`` for a component that drifts more than its probe
    noise within the check interval; components without statistics do not constrain it."""
    best = max_h
    for c, st in stats.items():
        if c not in gains or not st["lags_h"]:
            continue
        g = float(gains[c])
        tol = max(float(np.interp(check_h, st["lags_h"], st["yy"])), float((noise or {}).get(c, 0.0)) ** 2)
        limit = check_h
        for lag, yy, yp, pp in zip(st["lags_h"], st["yy"], st["yp"], st["pp"]):
            if lag > max_h + 1e-9 or yy - 2 * g * yp + g * g * pp > tol * (1 + 1e-9):
                break                                # the allowed range ends at the first lag that errs more
            limit = max(limit, float(lag))
        best = min(best, limit)
    return best


def build_cd_prior(recordings: Sequence[Any], config: Mapping[str, Any] | CdConfig | None = None, *,
                   machine: str = "", sources: Sequence[str] = (), every_s: float = 600.0,
                   max_anchor_points: int = 1500) -> dict[str, Any]:
    """The CD prior from nominal recordings (module docstring): inputs chosen on the last
    recording held out, whose RMS is the ``validation_rms``; diagrams fitted on all of them;
    ``anchors``: the training points (thinned evenly) the load-case updates keep close to."""
    if len(recordings) < 2:
        raise PriorError(f"cd prior: needs >= 2 training recordings (one held out), got {len(recordings)}")
    cfg = config if isinstance(config, CdConfig) else CdConfig.from_mapping(prior_config(config, machine))
    if not (math.isfinite(every_s) and every_s > 0):
        raise PriorError(f"cd prior: every_s {every_s!r} must be a positive number")
    parts, names = _training_parts(recordings, cfg, every_s)
    x = np.vstack([p[1] for p in parts])
    y = {c: np.concatenate([p[2][c] for p in parts]) for c in cfg.components}
    n_held = parts[-1][1].shape[0]
    if x.shape[0] - n_held < 2 ** cfg.max_inputs + 2 or n_held < 2:
        raise PriorError(f"cd prior: only {x.shape[0]} training points ({n_held} held out; every_s {every_s})")
    split = (np.arange(x.shape[0] - n_held), np.arange(x.shape[0] - n_held, x.shape[0]))

    def make(cols: list[int] | None = None) -> CharacteristicDiagram:
        return CharacteristicDiagram(n_intervals=cfg.n_intervals, smoothing=cfg.smoothing,
                                     extrapolate=extrapolated_axes(cfg, names, cols))

    inputs, cds, held, gain, stats = {}, {}, {}, {}, {}
    for c in cfg.components:
        steps = forward_selection(x, y[c], max_inputs=cfg.max_inputs, make_cd=make, seed=cfg.seed,
                                  min_relative_gain=0.05, split=split)
        cols = list(steps[-1].subset)
        inputs[c] = cols
        held[c] = float(steps[-1].score)            # RMS on the held-out programme, fitted without it
        cds[c] = make(cols).fit(x[:, cols], y[c]).to_state()
        lag = max(1, int(round(cfg.calibration_probe_interval_s / every_s)))
        without = make(cols).fit(x[split[0]][:, cols], y[c][split[0]])
        gain[c] = held_out_change_gain(without, x[split[1]][:, cols], y[c][split[1]], lag)
        stats[c] = held_out_change_stats(without, x[split[1]][:, cols], y[c][split[1]], every_s)
    thin = np.unique(np.linspace(0, x.shape[0] - 1, min(max_anchor_points, x.shape[0])).round().astype(int))
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "cd", "machine": machine,
            "sources": list(sources), "sensors": list(parts[0][0]), "candidate_names": list(names),
            "inputs": inputs, "input_names": {c: [names[i] for i in cols] for c, cols in inputs.items()},
            "cds": cds, "anchors": {"u": x[thin].tolist(), "y": {c: v[thin].tolist() for c, v in y.items()}},
            "validation_rms": held, "change_gain": gain, "change_stats": stats, "training_points": int(x.shape[0]),
            "training_check": training_check(cfg.components, x[split[1]], {c: v[split[1]] for c, v in y.items()},
                                             "held-out training recording"),
            "every_s": float(every_s),
            "cd_config": asdict(cfg), "adaptation": dict(DEFAULT_ADAPTATION)}


def cd_prior_from_state(state: Mapping[str, Any], machine: str = "",
                        sensors: Sequence[str] | None = None) -> dict[str, Any]:
    """A prior from the persisted CD model state (kind ``cd``) of another machine. A model started
    from a prior gives that prior with its own adaptation: its probes join the anchors, its
    measured change gain (walk-forward at its probe pairs) replaces the prior's and its load-case
    updates, if any, are folded into the diagrams (refitted on the anchors). A plain CD model gives
    its inputs and its diagrams refitted on all its probes with the temperatures as deltas from its
    first probe (its run's first instant), as a prior's. ``sensors``: the new machine's temperature
    channels; a state whose channels are not among them is refused."""
    if not isinstance(state, Mapping) or state.get("kind") != "cd":
        kind = state.get("kind") if isinstance(state, Mapping) else type(state).__name__
        raise PriorError(f"cd prior: the state's 'kind' is {kind!r}, expected 'cd' (a CD model state)")
    model = CharacteristicDiagramModel.from_state(dict(state))
    if isinstance(model, CdPriorModel):
        prior = _prior_of_adapted(model)
    elif model.phase != PHASE_COMPENSATION or not model.base:
        raise PriorError("cd prior: the given CD state has no fitted diagrams (still in calibration)")
    else:
        prior = _prior_of_plain(model)
    if sensors is not None:
        missing = [s for s in prior["sensors"] if s not in set(sensors)]
        if missing:
            raise PriorError(f"cd prior: the state's temperature channels {missing} are not the machine's "
                             f"({sorted(sensors)}): a state of another machine type")
    return {**prior, "machine": machine, "sources": ["persisted model state"]}


def _prior_of_adapted(model: "CdPriorModel") -> dict[str, Any]:
    prior = {**model.prior, "anchors": {"u": list(model.prior["anchors"]["u"]) + list(model.new_u),
                                        "y": {c: list(model.prior["anchors"]["y"][c]) + list(model.new_y[c])
                                              for c in model.component_names}}}
    prior["change_gain"] = {c: model.change_gain(c) for c in model.component_names}
    if model.update:
        u = np.asarray(prior["anchors"]["u"], float)
        make = model._make_cd
        prior["cds"] = {**prior["cds"], **{c: make(model.inputs[c]).fit(u[:, model.inputs[c]],
                                                                         [model._diagrams(r)[c] for r in u])
                                           .to_state() for c in model.update}}
    return prior


def _prior_of_plain(model: CharacteristicDiagramModel) -> dict[str, Any]:
    u = np.asarray(model.base_u + model.new_u, float)
    n = model.level_columns
    u[:, :n] -= u[0, :n]                              # deltas from the first probe, as a prior's inputs
    y = {c: np.asarray(model.base_y[c] + model.new_y[c], float) for c in model.component_names}
    cds = {c: model._make_cd(model.inputs[c]).fit(u[:, model.inputs[c]], y[c]) for c in model.component_names}
    gain = {c: change_gain(np.diff(y[c]), np.diff(cds[c].predict(u[:, model.inputs[c]]))) for c in cds}
    names = model.candidate_names
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "cd", "sensors": list(model.sensor_names),
            "candidate_names": names, "inputs": {c: list(v) for c, v in model.inputs.items()},
            "input_names": {c: [names[i] for i in v] for c, v in model.inputs.items()},
            "cds": {c: cd.to_state() for c, cd in cds.items()},
            "anchors": {"u": u.tolist(), "y": {c: v.tolist() for c, v in y.items()}},
            "validation_rms": {c: math.nan for c in cds}, "change_gain": gain,
            "training_points": int(u.shape[0]), "cd_config": asdict(model.config),
            "adaptation": dict(DEFAULT_ADAPTATION)}


@register_prior_model("cd")
class CdPriorModel(CharacteristicDiagramModel):
    """The CD model started from a prior: compensating from the first instant with the prior's
    diagrams, probing every ``calibration_probe_interval_s`` for ``check_s`` and then at the
    interval the measured gain allows (``interval_by_gain``; off: every ``update_probe_interval_s``),
    load-case updates only with ``load_case_updates``."""

    kind = "cd"

    def __init__(self, config: Mapping[str, Any] | None = None, prior: Mapping[str, Any] | None = None,
                 check_s: float | None = None):
        if not prior or prior.get("model_kind") != "cd":
            raise PriorError(f"cd prior: 'model_kind' is {(prior or {}).get('model_kind')!r}, expected 'cd'")
        cfg = dict(config or {})
        cfg.update({k: prior["cd_config"][k] for k in STRUCTURE_KEYS if k in prior["cd_config"]})
        cfg["sensors"] = list(prior["sensors"])
        adapt = {**DEFAULT_ADAPTATION, **prior.get("adaptation", {})}
        for key in ("update_batch", "update_rmse_floor"):
            cfg.setdefault(key, adapt[key])
        super().__init__(cfg)
        missing = [c for c in self.component_names if c not in prior["cds"]]
        if missing:
            raise PriorError(f"cd prior: no diagram for component(s) {missing} (prior has {sorted(prior['cds'])})")
        self.check_s = float(check_s if check_s is not None else adapt["check_s"])
        if not (math.isfinite(self.check_s) and self.check_s >= 0):
            raise PriorError(f"cd prior: check_s {self.check_s!r} must be a number >= 0")
        self.prior = dict(prior)
        self.x0: np.ndarray | None = None
        self.inputs = {c: list(prior["inputs"][c]) for c in self.component_names}
        self.base = {c: CharacteristicDiagram.from_state(prior["cds"][c]) for c in self.component_names}
        self.base_u = [list(r) for r in prior["anchors"]["u"]]
        self.base_y = {c: list(prior["anchors"]["y"][c]) for c in self.component_names}
        self.phase = PHASE_COMPENSATION
        self.message = "prior: compensating with the machine type's characteristic diagrams"
        self.hold.trust()
        self.anchored = bool(adapt.get("anchored", True))
        self.gain_window = int(adapt["gain_window"])
        self.min_pairs = int(adapt["min_pairs"])
        self.load_case_updates = bool(adapt["load_case_updates"])
        self.prior_gain = dict(prior.get("change_gain", {}))
        self.interval_by_gain = bool(adapt.get("interval_by_gain", False)) and bool(prior.get("change_stats"))
        self._interval_cache: tuple[tuple[int, int], float] | None = None
        self.min_q_prod_pct = float(adapt.get("min_q_prod_pct", 0.0))
        if not (math.isfinite(self.min_q_prod_pct) and 0.0 <= self.min_q_prod_pct < 100.0):
            raise PriorError(f"cd prior: min_q_prod_pct {self.min_q_prod_pct!r} must be a number in [0, 100)")
        #: probe noise std per component (um, um/m) the interval rule compares drifts with: the
        #: prior's adaptation ``probe_noise`` or Table 5.4's (0.25 um, 1.2 um/m)
        self.probe_noise = {**table_5_4_noise(self.component_names), **dict(adapt.get("probe_noise") or {})}
        if self.gain_window < 1:
            raise PriorError(f"cd prior: gain_window {self.gain_window!r} must be an integer >= 1")
        #: the last probe: time, measured total error, diagrams' values and inputs there
        self.anchor: dict[str, Any] | None = None
        #: walk-forward at the probe pairs: (hours between, measured change, predicted change)
        self.pairs = {c: deque(maxlen=self.gain_window) for c in self.component_names}

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        """The candidates with temperatures as deltas from the first complete row (as the prior)."""
        super().update_inputs(t_s, temperatures, machine_state)
        n = self.level_columns
        if self.x0 is None and np.all(np.isfinite(self.current)):
            self.x0 = self.current[:n].copy()
        if self.x0 is not None:
            self.current = self.current.copy()
            self.current[:n] -= self.x0

    def _diagrams(self, u: np.ndarray) -> dict[str, float]:
        """base + update of every component at the candidate vector ``u`` (not anchored)."""
        out = {}
        for c in self.component_names:
            x = np.asarray(u, float)[self.inputs[c]][None, :]
            out[c] = float(self.base[c].predict(x)[0]) + (float(self.update[c].predict(x)[0]) if c in self.update else 0.0)
        return out

    def change_gain(self, c: str) -> float:
        """Weight of the diagrams' predicted change since the last probe: the least-squares gain of
        the predicted on the measured changes at the walk-forward probe pairs, sum(d p) / sum(p^2),
        clipped to [0, 1]: 1 where the diagrams predict the changes, 0 where holding the probe is
        better (an uncorrelated or opposite prediction). Before ``min_pairs`` pairs: the prior's own
        gain, measured the same way on its held-out programme (``change_gain`` in the prior)."""
        pairs = self.pairs[c]
        if len(pairs) < self.min_pairs:
            return float(self.prior_gain.get(c, 1.0))
        return change_gain([x[1] for x in pairs], [x[2] for x in pairs])

    def _predict_raw(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        """The level of the last probe plus the diagrams' predicted change since it, weighted by
        :meth:`change_gain` (before any probe: the change since the first row, where the errors,
        deltas from the start, are 0)."""
        if self.current is None or not np.all(np.isfinite(self.current)):   # before the first complete row
            return {c: 0.0 for c in self.component_names}, {c: math.nan for c in self.component_names}
        if self._cache is not None and self._cache[0] == self._key:
            return dict(self._cache[1]), dict(self._cache[2])
        raw, stds = super()._predict_raw(t_s)
        if not self.anchored:
            return raw, stds
        if self.anchor is None:
            self.anchor = {"t": float(t_s), "y": {c: 0.0 for c in self.component_names},
                           "f": dict(raw), "u": self.current.tolist()}
        a = self.anchor
        values = {c: a["y"][c] + self.change_gain(c) * (raw[c] - a["f"][c]) for c in self.component_names}
        self._cache = (self._key, dict(values), dict(stds))
        return values, stds

    def _learn(self, t_s: float, measured: Mapping[str, float],
               applied_compensation: Mapping[str, float]) -> None:
        """The CD model's measurement (load-case update), then the walk-forward pair (the change the
        diagrams predicted since the last probe, before learning from this one, against the
        measured change) and the new anchor."""
        done = self.probing_cycles
        before = self._diagrams(self.current) if self.current is not None and self.anchor is not None else None
        u_prev = None if self.anchor is None else np.asarray(self.anchor["u"], float)
        prev = None if u_prev is None else self._diagrams(u_prev)
        super()._learn(t_s, measured, applied_compensation)
        if self.probing_cycles == done:                              # not learned from
            return
        totals = {c: float(measured[c]) + _finite(applied_compensation.get(c, 0.0)) for c in self.component_names}
        if before is not None and t_s > self.anchor["t"]:
            h = (t_s - self.anchor["t"]) / 3600.0
            for c in self.component_names:
                self.pairs[c].append((h, totals[c] - self.anchor["y"][c], before[c] - prev[c]))
        self.anchor = {"t": float(t_s), "y": totals, "f": self._diagrams(self.current), "u": self.current.tolist()}
        self._cache = None

    def _interval(self) -> float:
        checking = (self.t_start is None or self.t_last_probe is None
                    or self.t_last_probe - self.t_start < self.check_s)
        if checking:
            return self.config.calibration_probe_interval_s
        if not self.interval_by_gain:
            return self.config.update_probe_interval_s
        key = (self.probing_cycles, self.failed_probing_cycles)
        if self._interval_cache is None or self._interval_cache[0] != key:   # changes only with a probe
            gains = {c: self.change_gain(c) for c in self.component_names}
            stats = {c: v for c, v in self.prior["change_stats"].items() if c in gains}
            wanted = 3600.0 * interval_from_gain(
                stats, gains, self.config.calibration_probe_interval_s / 3600.0,
                self.config.update_probe_interval_s / 3600.0, self.probe_noise)
            self._interval_cache = (key, min(max(wanted, self._productivity_floor_s()),
                                             self.config.update_probe_interval_s))
        return self._interval_cache[1]

    def _productivity_floor_s(self) -> float:
        """The shortest interval after the last probing that keeps Q_prod >= ``min_q_prod_pct``
        once the next probing is done: (probing time + one probing) / (1 - q) - elapsed."""
        if self.min_q_prod_pct <= 0.0:
            return 0.0
        d = self.config.probe_duration_s
        probing = (self.probing_cycles + self.failed_probing_cycles + 1) * d
        elapsed = self.t_last_probe - self.t_start
        return max(0.0, probing / (1.0 - self.min_q_prod_pct / 100.0) - elapsed)

    def _fit_update(self) -> None:
        if self.load_case_updates:
            super()._fit_update()
        else:
            self.pending_since_update = 0

    def to_state(self) -> dict:
        return {**super().to_state(), "prior": self.prior, "check_s": self.check_s,
                "x0": None if self.x0 is None else self.x0.tolist(), "anchor": self.anchor,
                "pairs": {c: [list(p) for p in v] for c, v in self.pairs.items()}}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "CdPriorModel":
        if not state.get("prior"):
            raise PriorError("cd prior: model state has no 'prior'")
        base = {k: v for k, v in state.items() if k not in ("anchor", "pairs")}
        model = restore_with_prior(cls(state["config"], state["prior"], state["check_s"]),
                                   CharacteristicDiagramModel, base)
        model.anchor = state.get("anchor")
        for c, pairs in (state.get("pairs") or {}).items():
            model.pairs[c].extend(tuple(p) for p in pairs)
        return model


def _finite(v) -> float:
    return 0.0 if v is None or not math.isfinite(float(v)) else float(v)


def cd_with_prior(config: Mapping[str, Any], prior: Mapping[str, Any], **kwargs) -> CdPriorModel:
    """The run's CD model started from ``prior`` (from :func:`build_cd_prior` / ``thermal-comp prior``)."""
    return CdPriorModel(config, prior, **kwargs)
