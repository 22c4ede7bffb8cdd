"""Re-fitting a ridge model at each probing (adaptive mode of ``evaluate``, docs/evaluate.md).

The lagged / low-pass ridge is fitted on the training rows. At each probing the displacement
is read exactly, and the temperatures before it are known, so the probe row is one more
training row. The model is re-fitted on the training rows plus every probe row so far, each
probe row weighted ``weight`` x the number of training rows (``weight`` = 0.01: a probe counts
as 1 % of the training set). It is a weighted ridge with the rows appended, so it is exact and
cheap: the training rows' normal equations are kept and each probe adds one outer product.
The features' standardisation, the time constants and the penalty stay those of training; the
intercept is free (not penalised), and with ``own_level`` the probe rows get an intercept of
their own (a level shift after calibration that does not bend the coefficients).
Between probings the compensation is the re-fitted model's prediction plus its residual at the
last probe. ``weight`` = 0 is the training model exactly.

``weight`` and ``own_level`` are chosen on the training rows only (:func:`choose_refit`): the
model fitted on their first half, probed at the budget's interval over the second half, MAE
averaged over probe phases as :func:`talc_model.open_loop.probe_gain_update.choose_update` does.

:class:`ProbeRefitModel` (kind ``probe_refit``) is the same re-fit as a streaming adaptive model:
the training rows are its calibration probes, each later probe one more weighted row.
No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import register_model
from talc_model.open_loop.lagged_temperature_model import LaggedTemperatureModel
from talc_model.open_loop.probe_gain_update import regular_probes
from talc_model.open_loop.probed_lagged import ProbedLaggedModel

#: candidate probe-row weights, as a share of the training rows' total weight (0: no re-fit)
WEIGHTS = (0.0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3)
#: the probe rows share the training intercept, or have a level of their own
LEVELS = (False, True)
#: ``evaluate`` rows whose adaptive mode re-fits the ridge at each probing (opt-in rows)
REFIT_ROWS = ("lagged_ridge_refit", "lowpass_ridge_refit")


class RefitError(ValueError):
    """Bad input to the re-fit; the message names the argument and value."""


def refit_solve(gram: np.ndarray, zy: np.ndarray, n_rows: int, alpha: float, own_level: bool,
                probe_a: np.ndarray | None = None, probe_b: np.ndarray | None = None) -> np.ndarray:
    """The feature coefficients of the ridge (training normal equations ``gram``, ``zy`` of
    ``n_rows`` centred rows, penalty ``alpha``) plus the weighted probe rows' normal equations
    ``probe_a``, ``probe_b`` over [intercept(s), features] (None: no probe row)."""
    m = gram.shape[0]
    if probe_a is None:
        a = gram + alpha * np.eye(m)
        return np.linalg.solve(a, zy) if alpha > 0 else np.linalg.lstsq(a, zy, rcond=None)[0]
    k = 2 if own_level else 1                    # unpenalised intercept(s) first
    a = np.zeros((k + m, k + m))
    a[0, 0] = n_rows                             # Z is centred on the training rows
    a[k:, k:] = gram + alpha * np.eye(m)
    b = np.concatenate([np.zeros(k), zy])
    a += probe_a
    b += probe_b
    return np.linalg.lstsq(a, b, rcond=None)[0][k:] if alpha == 0 else np.linalg.solve(a, b)[k:]


def probe_row(z: np.ndarray, own_level: bool) -> np.ndarray:
    """A probe row of the re-fit: its intercept column(s), then its standardised features."""
    return np.concatenate([np.ones(2 if own_level else 1), z])


@dataclass(frozen=True)
class RidgeRefit:
    """A ridge fitted on training rows, ready to be re-fitted with weighted probe rows."""

    z: np.ndarray            # standardised features of every row (training mean and scale)
    gram: np.ndarray         # Z'Z over the finite training rows
    zy: np.ndarray           # Z'(y - ym) over them
    n_rows: int              # finite training rows
    ym: float                # the training intercept (mean displacement)
    alpha: float             # the training penalty
    weight: float = 0.0      # each probe row's weight, as a share of the n_rows training rows
    own_level: bool = False  # the probe rows' own intercept

    def __post_init__(self) -> None:
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise RefitError(f"weight: {self.weight!r} must be a finite number >= 0")

    def with_update(self, weight: float, own_level: bool) -> "RidgeRefit":
        return replace(self, weight=float(weight), own_level=bool(own_level))

    def coefficients(self, y: np.ndarray, probes: Sequence[int]) -> np.ndarray:
        """The feature coefficients re-fitted on the training rows plus ``probes`` (rows of
        ``y`` read there only; a NaN reading is skipped)."""
        probes = [int(r) for r in probes if math.isfinite(y[r])]
        if self.weight == 0 or not probes:
            return refit_solve(self.gram, self.zy, self.n_rows, self.alpha, self.own_level)
        d = np.column_stack([np.ones((len(probes), 2 if self.own_level else 1)), self.z[probes]])
        w = self.weight * self.n_rows
        return refit_solve(self.gram, self.zy, self.n_rows, self.alpha, self.own_level,
                           w * d.T @ d, w * d.T @ (np.asarray(y, float)[probes] - self.ym))

    def compensation(self, y: np.ndarray, measured: Sequence[int], start: int, stop: int) -> np.ndarray:
        """c(t) on rows [start, stop): the model re-fitted at the last measurement strictly
        before each row (``measured[1:]`` are the probes so far; ``measured[0]`` < ``start`` is
        the last training row), plus its residual there; NaN elsewhere. Reads ``y`` at measured
        rows only."""
        m = np.asarray(measured, int)
        if m.size == 0 or m[0] >= start:
            raise RefitError(f"measured: {m[:3].tolist()!r}... must start with a row before {start}")
        out = np.full(self.z.shape[0], np.nan)
        bounds = list(m[1:]) + [stop - 1]
        lo = start
        for i, hi in enumerate(bounds):
            if hi < lo:
                continue
            coef = self.coefficients(y, m[1:i + 1])
            r = m[i]
            out[lo:hi + 1] = y[r] + (self.z[lo:hi + 1] - self.z[r]) @ coef
            lo = hi + 1
        return out


def ridge_refit(time_s: np.ndarray, temperatures: np.ndarray, y: np.ndarray, n_fit: int, taus_s: Sequence[float],
                alpha: float, weight: float = 0.0, own_level: bool = False) -> RidgeRefit:
    """The lagged ridge (:class:`LaggedTemperatureModel`, ``taus_s``, ``alpha``) fitted on rows
    < ``n_fit`` as :func:`thermal_eval.evaluate.open_loop_models` fits it, kept as normal equations."""
    model = LaggedTemperatureModel(tuple(taus_s), alpha)
    model.fit_recording(time_s[:n_fit], temperatures[:n_fit], y[:n_fit])
    z = (model.features(time_s, temperatures) - model.mean_) / model.scale_
    ok = np.flatnonzero(np.isfinite(y[:n_fit]))
    zt = z[ok]
    return RidgeRefit(z, zt.T @ zt, zt.T @ (y[ok] - model.intercept_), ok.size, float(model.intercept_),
                      float(alpha), float(weight), bool(own_level))


def choose_refit(time_s: np.ndarray, y: np.ndarray, fitted: RidgeRefit, first: int, stop: int, every_s: float,
                 phases: int = 1, weights: Sequence[float] = WEIGHTS, levels: Sequence[bool] = LEVELS
                 ) -> tuple[tuple[float, bool], dict[str, float]]:
    """The (weight, own_level) with the smallest MAE on training rows [first, stop) of the model
    ``fitted`` on rows < ``first``, probed every ``every_s``, averaged over ``phases`` phases of
    that schedule: (best, mean MAE by "weight" or "weight/level")."""
    if not 0 < first < stop <= len(y):
        raise RefitError(f"walk-forward rows [{first}, {stop}) are not inside the {len(y)} rows")
    if not (isinstance(phases, int) and phases >= 1):
        raise RefitError(f"phases: {phases!r} must be an integer >= 1")
    schedules = [[first - 1] + regular_probes(time_s, first, stop, every_s, i * every_s / phases)
                 for i in range(phases)]
    candidates = [(w, lv) for w in weights for lv in (levels if w > 0 else (False,))]
    scores: dict[str, float] = {}
    for w, lv in candidates:
        upd = fitted.with_update(w, lv)
        maes = []
        for measured in schedules:
            e = np.abs(y[first:stop] - upd.compensation(y, measured, first, stop)[first:stop])
            maes.append(float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any() else math.inf)
        scores[f"{w:g}/{'own' if lv else 'shared'}"] = float(np.mean(maes))
    best = min(candidates, key=lambda c: scores[f"{c[0]:g}/{'own' if c[1] else 'shared'}"])
    return (float(best[0]), bool(best[1])), scores


def refit_choice(data, channel: str, params: dict, n_first: int, every_s: float, phases: int
                 ) -> tuple[RidgeRefit, dict]:
    """For ``evaluate``: the ridge (params ``taus_s``, ``alpha`` from the training selection)
    fitted on rows < n_train with the weight and level chosen by the walk-forward inside the
    training rows (fitted on rows < ``n_first``), and the JSON of that choice."""
    n_train = data.split.n_train
    y = data.displacement_um[channel]
    taus, alpha = params["taus_s"], params["alpha"]
    half = ridge_refit(data.time_s, data.temperatures, y, n_first, taus, alpha)
    (w, lv), scores = choose_refit(data.time_s, y, half, n_first, n_train, every_s, phases)
    info = {"weight": w, "own_level": lv, "walk_forward_rows": [n_first, n_train], "walk_forward_phases": phases,
            "walk_forward_mae_um": {k: round(v, 3) for k, v in scores.items()}}
    return ridge_refit(data.time_s, data.temperatures, y, n_train, taus, alpha, w, lv), info


@register_model("probe_refit")
class ProbeRefitModel(ProbedLaggedModel):
    """A lagged ridge re-fitted at each probe on its calibration probes plus every later probe,
    each weighted ``weight`` x the calibration probes (``own_level``: the later probes' own
    intercept); between probes the re-fitted model plus its residual at the last probe."""

    DEFAULTS = {"weight": 0.01, "own_level": False}

    def _check(self, cfg: Mapping[str, Any]) -> None:
        w = cfg["weight"]
        if not (isinstance(w, (int, float)) and math.isfinite(w) and w >= 0):
            raise RefitError(f"weight: {w!r} must be a finite number >= 0")
        if not isinstance(cfg["own_level"], bool):
            raise RefitError(f"own_level: {cfg['own_level']!r} must be true or false")

    def _start(self, c: str, x: np.ndarray, y: np.ndarray) -> None:
        z = self.standardised(c, x)
        k = 2 if self.config["own_level"] else 1
        m = z.shape[1]
        self.last[c] = {"gram": z.T @ z, "zy": z.T @ (y - self.ridges[c].intercept_), "n_rows": int(y.size),
                        "probe_a": np.zeros((k + m, k + m)), "probe_b": np.zeros(k + m), "probes": 0,
                        "coef": np.asarray(self.ridges[c].coef_, float), "y": float(y[-1]), "z": z[-1].copy()}

    def _learn(self, c: str, x: np.ndarray, y: float) -> None:
        v = self.last[c]
        z = self.standardised(c, x)
        d = probe_row(z, self.config["own_level"])
        v["probe_a"] += np.outer(d, d)
        v["probe_b"] += d * (y - self.ridges[c].intercept_)
        v["probes"] += 1
        w = float(self.config["weight"]) * v["n_rows"]
        if w > 0:
            v["coef"] = refit_solve(v["gram"], v["zy"], v["n_rows"], float(self.config["alpha"]),
                                    self.config["own_level"], w * v["probe_a"], w * v["probe_b"])
        v["y"], v["z"] = float(y), z

    def _value(self, c: str, x: np.ndarray) -> float:
        v = self.last[c]
        return v["y"] + float((self.standardised(c, x) - v["z"]) @ v["coef"])

    def _rule_state(self) -> dict[str, Any]:
        return {c: {k: (val.tolist() if isinstance(val, np.ndarray) else val) for k, val in v.items()}
                for c, v in self.last.items()}

    def _load_rule_state(self, state: Mapping[str, Any]) -> None:
        for c, v in state.items():
            self.last[c] = {k: (np.asarray(val, float) if isinstance(val, list) else val) for k, val in v.items()}
