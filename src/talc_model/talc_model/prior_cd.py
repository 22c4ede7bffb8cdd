"""A characteristic-diagram prior from the machine type, and the CD model started from it.

``build_cd_prior`` fits one CD per error component on virtual experiments of the NOMINAL type
(other load programmes and seeds than the run; ``thermal-comp prior --model cd``): the
candidate inputs are exactly the CD model's online ones (every temperature as a delta from the
run's first row, and its gradient), chosen by the forward heuristic scored on the LAST
training recording held out (a prior must generalise to an unseen programme), then fitted on
all recordings. ``CdPriorModel`` (kind ``cd``) compensates with those diagrams from the first
instant, probes at the calibration interval for ``check_s`` and then at the update interval,
and adapts with the CD papers' load-case update (the prior's training points are the anchors,
the unit's probes the new load case). No rclpy here. docs/prior.md, docs/agp_cd.md.
"""
from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import PHASE_COMPENSATION
from talc_model.cd_input_selection import forward_selection
from talc_model.cd_model import CdConfig, CharacteristicDiagramModel
from talc_model.characteristic_diagram import CharacteristicDiagram
from talc_model.prior import PRIOR_VERSION, PriorError
from talc_model.prior_agp import error_deltas, restore_with_prior

#: adaptation settings stored in the prior (the run's configuration overrides the CD-model keys):
#: a load-case update after every probe, its stop rule floored at twice the linear probe noise
#: (measured on 48 h of talc-178h-dry, unit #1: batches of 3 or 6 left P99_lin 14.1 / 26.7 um
#: against 11.6 um with 1; floor 0: 27.5 against 24.2 um over 178 h with batch 6)
DEFAULT_ADAPTATION = {"check_s": 4 * 3600.0, "update_batch": 1, "update_rmse_floor": 0.5}
#: the CD structure is the prior's: these run-configuration keys are taken from it
STRUCTURE_KEYS = ("sensors", "use_gradients", "gradient_window_s", "max_inputs", "n_intervals", "smoothing")


def cd_inputs(recording, config: CdConfig) -> tuple[list[str], list[str], np.ndarray]:
    """(sensors, candidate names, rows): the candidate inputs the CD model sees online, one row
    per recording row (fed through a :class:`CharacteristicDiagramModel`, so NaN holding and
    the gradient window are the model's), temperatures as deltas from the first complete row."""
    probe = CharacteristicDiagramModel(asdict(config))
    sensors = {c[:-2]: np.asarray(recording.columns[c], float) for c in recording.names("sensor")}
    rows = []
    for k, t in enumerate(np.asarray(recording.time_s, float)):
        probe.update_inputs(float(t), {s: float(v[k]) for s, v in sensors.items()}, {})
        rows.append(probe.current.copy())
    x = np.asarray(rows)
    n = len(probe.sensor_names)
    ok = np.all(np.isfinite(x), axis=1)
    if ok.any():
        x[:, :n] -= x[ok][0, :n]
    return list(probe.sensor_names), probe.candidate_names, x


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


def build_cd_prior(recordings: Sequence[Any], config: Mapping[str, Any] | CdConfig | None = None, *,
                   machine: str = "", sources: Sequence[str] = (), every_s: float = 600.0,
                   max_anchor_points: int = 1500) -> dict[str, Any]:
    """The CD prior from nominal recordings (module docstring): inputs chosen on the last
    recording held out, whose RMS is the ``validation_rms``; diagrams fitted on all of them;
    ``anchors``: the training points (thinned evenly) the load-case updates keep close to."""
    cfg = config if isinstance(config, CdConfig) else CdConfig.from_mapping(dict(config or {}))
    if len(recordings) < 2:
        raise PriorError(f"cd prior: needs >= 2 training recordings (one held out), got {len(recordings)}")
    if not (math.isfinite(every_s) and every_s > 0):
        raise PriorError(f"cd prior: every_s {every_s!r} must be a positive number")
    parts, names = _training_parts(recordings, cfg, every_s)
    x = np.vstack([p[1] for p in parts])
    y = {c: np.concatenate([p[2][c] for p in parts]) for c in cfg.components}
    n_held = parts[-1][1].shape[0]
    if x.shape[0] - n_held < 2 ** cfg.max_inputs + 2 or n_held < 2:
        raise PriorError(f"cd prior: only {x.shape[0]} training points ({n_held} held out; every_s {every_s})")
    split = (np.arange(x.shape[0] - n_held), np.arange(x.shape[0] - n_held, x.shape[0]))

    def make() -> CharacteristicDiagram:
        return CharacteristicDiagram(n_intervals=cfg.n_intervals, smoothing=cfg.smoothing)

    inputs, cds, held = {}, {}, {}
    for c in cfg.components:
        steps = forward_selection(x, y[c], max_inputs=cfg.max_inputs, make_cd=make, seed=cfg.seed,
                                  min_relative_gain=0.05, split=split)
        cols = list(steps[-1].subset)
        inputs[c] = cols
        held[c] = float(steps[-1].score)            # RMS on the held-out programme, fitted without it
        cds[c] = make().fit(x[:, cols], y[c]).to_state()
    thin = np.unique(np.linspace(0, x.shape[0] - 1, min(max_anchor_points, x.shape[0])).round().astype(int))
    return {"kind": "prior", "version": PRIOR_VERSION, "model_kind": "cd", "machine": machine,
            "sources": list(sources), "sensors": list(parts[0][0]), "candidate_names": list(names),
            "inputs": inputs, "input_names": {c: [names[i] for i in cols] for c, cols in inputs.items()},
            "cds": cds, "anchors": {"u": x[thin].tolist(), "y": {c: v[thin].tolist() for c, v in y.items()}},
            "validation_rms": held, "training_points": int(x.shape[0]), "every_s": float(every_s),
            "cd_config": asdict(cfg), "adaptation": dict(DEFAULT_ADAPTATION)}


class CdPriorModel(CharacteristicDiagramModel):
    """The CD model started from a prior: compensating from the first instant with the prior's
    diagrams, probing every ``calibration_probe_interval_s`` for ``check_s`` and then every
    ``update_probe_interval_s``, a load-case update after every ``update_batch`` probes (the
    prior's adaptation default 1 unless the run's configuration sets it)."""

    kind = "cd"

    def __init__(self, config: Mapping[str, Any] | None = None, prior: Mapping[str, Any] | None = None,
                 check_s: float | None = None):
        if not prior or prior.get("model_kind") != "cd":
            raise PriorError(f"cd prior: 'model_kind' is {(prior or {}).get('model_kind')!r}, expected 'cd'")
        cfg = dict(config or {})
        cfg.update({k: prior["cd_config"][k] for k in STRUCTURE_KEYS})
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

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None:
        """The candidates with temperatures as deltas from the first complete row (as the prior)."""
        super().update_inputs(t_s, temperatures, machine_state)
        n = len(self.sensor_names or [])
        if self.x0 is None and np.all(np.isfinite(self.current)):
            self.x0 = self.current[:n].copy()
        if self.x0 is not None:
            self.current = self.current.copy()
            self.current[:n] -= self.x0

    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        if self.current is None or not np.all(np.isfinite(self.current)):   # before the first complete row
            return {c: 0.0 for c in self.component_names}, {c: math.nan for c in self.component_names}
        return super().predict(t_s)

    def _interval(self) -> float:
        checking = (self.t_start is None or self.t_last_probe is None
                    or self.t_last_probe - self.t_start < self.check_s)
        return self.config.calibration_probe_interval_s if checking else self.config.update_probe_interval_s

    def to_state(self) -> dict:
        return {**super().to_state(), "prior": self.prior, "check_s": self.check_s,
                "x0": None if self.x0 is None else self.x0.tolist()}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "CdPriorModel":
        if not state.get("prior"):
            raise PriorError("cd prior: model state has no 'prior'")
        return restore_with_prior(cls(state["config"], state["prior"], state["check_s"]),
                                  CharacteristicDiagramModel, state)


def cd_with_prior(config: Mapping[str, Any], prior: Mapping[str, Any], **kwargs) -> CdPriorModel:
    """The run's CD model started from ``prior`` (from :func:`build_cd_prior` / ``thermal-comp prior``)."""
    return CdPriorModel(config, prior, **kwargs)
