"""Re-estimating a model's gain per input from its probes (adaptive mode of ``evaluate``).

A linear model's open-loop prediction is a sum of per-input contributions, p = p0 + sum_j x_j
(for an ARX model, x_j = B_j(q)/A(q) u_j simulated; linearity). After calibration the machine's
sensitivities drift from the fitted ones, so between two probings the displacement changes by
dy = dp + sum_j d_j dx_j + e, with d_j the relative error of input j's gain. Each pair of
consecutive probings gives one such equation; the gain errors d are re-estimated by ridge
regression on all pairs so far, shrunk towards 0 (the calibrated gains) by ``penalty`` (um^2 of
contribution change per unit gain error: the prior's precision over the noise's). Between
probings the compensation starts from the last probe and follows the re-gained model:

    c(t) = y(t_p) + [p(t) + sum_j d_j x_j(t)] - [p(t_p) + sum_j d_j x_j(t_p)].

``penalty`` is chosen on the training rows by walk-forward (:func:`choose_penalty`), never on
held-out rows. ``forgetting`` f <= 1 down-weights each older pair by f per probing (the prior is
not forgotten), so gains that drift are followed; f = 1 is the plain update. :func:`choose_update`
chooses penalty and forgetting together on the walk-forward averaged over probe phases.

:class:`ProbeGainUpdateModel` (kind ``probe_gain_update``) is the same update as a streaming
adaptive model: a lagged ridge calibrated on its first probes, each input being one feature of
it (:func:`lagged_contributions`), its gains re-estimated at each later probe.
No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import register_model
from talc_model.open_loop.probed_lagged import ProbedLaggedModel

#: candidate penalties (um^2 per unit gain error), from nearly free gains to nearly fixed ones
PENALTIES = (1.0, 10.0, 100.0, 1000.0)
#: candidate forgetting factors per probing (1: every pair counts the same)
FORGETTINGS = (1.0, 0.9, 0.8, 0.7, 0.5)


class GainUpdateError(ValueError):
    """Bad input to the gain update; the message names the argument and value."""


class GainRidge:
    """The ridge of the gain errors, fed one pair of consecutive probings at a time: the prior
    ``penalty`` x I (never forgotten) plus the pairs, each older one weighted ``forgetting`` less."""

    def __init__(self, n_inputs: int, penalty: float, forgetting: float = 1.0):
        if not (math.isfinite(penalty) and penalty > 0):
            raise GainUpdateError(f"penalty: {penalty!r} must be a finite number > 0")
        if not (math.isfinite(forgetting) and 0 < forgetting <= 1):
            raise GainUpdateError(f"forgetting: {forgetting!r} must be in (0, 1]")
        self.prior = penalty * np.eye(n_inputs)
        self.forgetting = forgetting
        self.a = self.prior.copy()
        self.b = np.zeros(n_inputs)

    def add_pair(self, dx: np.ndarray, z: float) -> np.ndarray:
        """One pair: contribution changes ``dx`` and the unexplained displacement change ``z``
        (NaN: only the fading); the gain errors in force after it."""
        if self.forgetting < 1:           # the pairs fade, the prior does not
            self.a = self.prior + self.forgetting * (self.a - self.prior)
            self.b *= self.forgetting
        if math.isfinite(z):
            self.a += np.outer(dx, dx)
            self.b += dx * z
        return np.linalg.solve(self.a, self.b)


def lagged_contributions(model, features: np.ndarray) -> np.ndarray:
    """Each feature's share of a fitted lagged ridge's prediction (rows x features): coef_j
    (x_j - mean_j) / scale_j; they add up to the prediction minus the intercept."""
    return (np.asarray(features, float) - model.mean_) / model.scale_ * model.coef_


def gain_errors(y: np.ndarray, p: np.ndarray, contributions: np.ndarray, measured: Sequence[int],
                penalty: float, forgetting: float = 1.0) -> np.ndarray:
    """The gain errors d in force after each measurement (row i: after ``measured[i]``): ridge on
    the pairs of consecutive measurements up to it, each older pair weighted ``forgetting`` times
    less per probing. Reads ``y`` at measured rows only."""
    x = np.nan_to_num(np.asarray(contributions, float))
    ridge = GainRidge(x.shape[1] if x.ndim == 2 else 0, penalty, forgetting)
    if x.ndim != 2 or x.shape[0] != len(p):
        raise GainUpdateError(f"contributions: shape {x.shape} must be (rows={len(p)}, inputs)")
    m = np.asarray(measured, int)
    out = [np.zeros(x.shape[1])]
    for prev, r in zip(m[:-1], m[1:]):
        out.append(ridge.add_pair(x[r] - x[prev], (y[r] - y[prev]) - (p[r] - p[prev])))
    return np.asarray(out)


def regained_compensation(y: np.ndarray, p: np.ndarray, contributions: np.ndarray, measured: Sequence[int],
                          start: int, stop: int, penalty: float, forgetting: float = 1.0) -> np.ndarray:
    """c(t) on rows [start, stop) from the last measurement strictly before each row (a probe row
    is compensated before its probe); NaN elsewhere. ``measured[0]`` < ``start``."""
    m = np.asarray(measured, int)
    if m.size == 0 or m[0] >= start:
        raise GainUpdateError(f"measured: {m[:3].tolist()!r}... must start with a row before {start}")
    d = gain_errors(y, p, contributions, m, penalty, forgetting)
    x = np.nan_to_num(np.asarray(contributions, float))
    rows = np.arange(start, stop)
    seg = np.searchsorted(m, rows, side="left") - 1
    mr = m[seg]
    out = np.full(len(p), np.nan)
    out[rows] = (y[mr] + p[rows] - p[mr] + np.sum(d[seg] * (x[rows] - x[mr]), axis=1))
    return out


def regular_probes(time_s: np.ndarray, start: int, stop: int, every_s: float, phase_s: float = 0.0) -> list[int]:
    """Rows of a probing every ``every_s`` after row ``start - 1`` + ``phase_s`` (the walk-forward's
    schedule: at a budget of one per hour the cap puts the probings on the hour)."""
    t = np.asarray(time_s, float)
    rows, nxt = [], t[start - 1] + phase_s + every_s
    for r in range(start, stop):
        if t[r] >= nxt:
            rows.append(r)
            nxt = t[r] + every_s
    return rows


def choose_update(time_s: np.ndarray, y: np.ndarray, p_fit: np.ndarray, contributions_fit: np.ndarray,
                  first: int, stop: int, every_s: float, penalties: Sequence[float] = PENALTIES,
                  forgettings: Sequence[float] = (1.0,), phases: int = 1
                  ) -> tuple[tuple[float, float], dict[str, float]]:
    """The (penalty, forgetting) with the smallest MAE on training rows [first, stop) of a model
    fitted on rows < ``first`` (``p_fit``, ``contributions_fit``) probed every ``every_s``, the MAE
    averaged over ``phases`` phases of that schedule (delayed by i/phases of ``every_s``):
    (best, mean MAE by "penalty" or "penalty/forgetting")."""
    if not 0 < first < stop <= len(y):
        raise GainUpdateError(f"walk-forward rows [{first}, {stop}) are not inside the {len(y)} rows")
    schedules = [[first - 1] + regular_probes(time_s, first, stop, every_s, i * every_s / phases)
                 for i in range(phases)]
    scores: dict[str, float] = {}
    key = (lambda pen, f: f"{pen:g}") if tuple(forgettings) == (1.0,) else (lambda pen, f: f"{pen:g}/{f:g}")
    for pen in penalties:
        for f in forgettings:
            maes = []
            for measured in schedules:
                c = regained_compensation(y, p_fit, contributions_fit, measured, first, stop, pen, f)
                e = np.abs(y[first:stop] - c[first:stop])
                maes.append(float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any() else math.inf)
            scores[key(pen, f)] = float(np.mean(maes))
    best = min(((pen, f) for pen in penalties for f in forgettings), key=lambda pf: scores[key(*pf)])
    return (float(best[0]), float(best[1])), scores


def choose_penalty(time_s: np.ndarray, y: np.ndarray, p_fit: np.ndarray, contributions_fit: np.ndarray,
                   first: int, stop: int, every_s: float, penalties: Sequence[float] = PENALTIES
                   ) -> tuple[float, dict[str, float]]:
    """The penalty with the smallest MAE on training rows [first, stop) of a model fitted on rows
    < ``first`` (``p_fit``, ``contributions_fit``) probed every ``every_s``: (best, MAE by penalty)."""
    (best, _), scores = choose_update(time_s, y, p_fit, contributions_fit, first, stop, every_s, penalties)
    return best, scores


@register_model("probe_gain_update")
class ProbeGainUpdateModel(ProbedLaggedModel):
    """A lagged ridge whose per-feature gains the probes re-estimate (:class:`GainRidge`); between
    probes c(t) = y(t_p) + [p(t) + sum_j d_j x_j(t)] - [p(t_p) + sum_j d_j x_j(t_p)], t_p the last
    probe (the last calibration probe until the first compensation probe)."""

    DEFAULTS = {"penalty": 100.0, "forgetting": 1.0}

    def _check(self, cfg: Mapping[str, Any]) -> None:
        GainRidge(1, float(cfg["penalty"]), float(cfg["forgetting"]))      # names a bad value

    def _start(self, c: str, x: np.ndarray, y: np.ndarray) -> None:
        self.last[c] = {"ridge": GainRidge(x.shape[1], float(self.config["penalty"]), float(self.config["forgetting"])),
                        "d": np.zeros(x.shape[1]), "y": float(y[-1]), "x": x[-1].copy()}

    def _parts(self, c: str, x: np.ndarray) -> tuple[float, np.ndarray]:
        r = self.ridges[c]
        return float(r.predict(x[None, :])[0]), lagged_contributions(r, x)

    def _learn(self, c: str, x: np.ndarray, y: float) -> None:
        last = self.last[c]
        p, contrib = self._parts(c, x)
        p_p, contrib_p = self._parts(c, last["x"])
        last["d"] = last["ridge"].add_pair(contrib - contrib_p, (y - last["y"]) - (p - p_p))
        last["y"], last["x"] = float(y), np.asarray(x, float).copy()

    def _value(self, c: str, x: np.ndarray) -> float:
        last = self.last[c]
        p, contrib = self._parts(c, x)
        p_p, contrib_p = self._parts(c, last["x"])
        return last["y"] + p - p_p + float(np.sum(last["d"] * (contrib - contrib_p)))

    def _rule_state(self) -> dict[str, Any]:
        return {c: {"a": v["ridge"].a.tolist(), "b": v["ridge"].b.tolist(), "d": v["d"].tolist(), "y": v["y"],
                    "x": v["x"].tolist()} for c, v in self.last.items()}

    def _load_rule_state(self, state: Mapping[str, Any]) -> None:
        for c, v in state.items():
            ridge = GainRidge(len(v["b"]), float(self.config["penalty"]), float(self.config["forgetting"]))
            ridge.a, ridge.b = np.asarray(v["a"], float), np.asarray(v["b"], float)
            self.last[c] = {"ridge": ridge, "d": np.asarray(v["d"], float), "y": float(v["y"]),
                            "x": np.asarray(v["x"], float)}
