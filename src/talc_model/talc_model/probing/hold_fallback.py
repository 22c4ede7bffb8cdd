"""When a model's prediction is not worth more than its last probe: hold the probe (part of every model).

An adaptive model that predicts worse than holding its own last probe costs the machine accuracy
for nothing. :class:`HoldFallback` keeps, per component, a prequential (out-of-sample) score of
the model against the hold-last-probe predictor and switches the component's output between the
two with a significance and hysteresis rule.

Like with like: at every probe, BEFORE the model learns from it, the model's prediction made just
before the probe (the last :meth:`output` call) and the previous probe's value are both compared
with the new probe's total error, at the same instant: model |P1 - M|, holding |P1 - P0|. Both
carry the new probe's noise; holding also the held probe's, and it keeps that one for the whole
interval (the parts see it), so it is part of holding's error. Over the last ``window`` scored
probes (:func:`window_scores`):

- noise: the probe noise std per component (the model's configured one, Table 5.4 by default)
  capped by what the probes allow: second differences of the probed values (a drift linear over
  two intervals cancels) bound it from above (median, robust to load steps); a quantised signal
  (resolution found) has none: its held value is exact while the signal stays in its quantum;
- the model's mean |error| against the truth: mean |P1 - M| with the new probe's noise taken
  out in quadrature (exact for Gaussian errors: E|e + n| = sqrt(2/pi) sqrt(s_e^2 + s_n^2));
- holding's interval-mean |error|: the drift part of |P1 - P0| (both probes' noise taken out in
  quadrature), scaled as a random walk (square root of time) to the model's regular probing
  interval ``horizon_s`` or the window's longest interval, halved (holding starts each interval
  exact and ends |drift| off: a linear drift or a quantum step at a random instant give half),
  plus the held probe's noise in quadrature. Mean absolute, not squared: on a quantised or
  plateau-like signal holding is exact most of the time and one step off the rest, which a mean
  square rates worse than a model's small errors everywhere although its mean error is lower;
  the model's error at the probe stands for its interval (conservative for a model that restarts
  from each probe, right for one whose error is stationary);
- switch: ratio = model / holding; model -> hold once ratio > ``TO_HOLD_RATIO``, hold -> model
  once ratio < ``TO_MODEL_RATIO`` (hysteresis), never before MIN_SCORED; leaving the start mode
  (hold for a model from zero, the model for one from a prior) also needs the difference to
  exceed ``SIGNIFICANCE`` standard errors of the per-probe differences: the burden of proof is
  on the change, and a return to the start mode needs none.

A model in its calibration phase has no prediction yet and holds its last probe. A model started
from a prior or a pretrained model starts in model mode (:meth:`HoldFallback.trust`), one from
zero starts holding and earns the model mode. A hold is only as good as its evidence: a held
probe older than the longest interval the score covers is compared with the model again, holding's
error extrapolated as a random walk (unscored: the model's output), so a model that stops probing
(the AGP between uncertainty-triggered probings) is not left on a stale probe. Quantised or
plateau-like error signals are detected from the probed values and said in :meth:`note`. No rclpy.
docs/talc.md, "Never clearly worse than holding".
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Iterable, Mapping

import numpy as np

from thermal_comp_common.probe_and_hold import table_5_4_noise

MODE_MODEL = "model"
MODE_HOLD = "hold"
#: scored probes a decision looks back on
WINDOW = 8
#: scored probes before the first switch
MIN_SCORED = 3
#: model mode -> hold above this ratio of interval mean |e|; hold -> model below the second
TO_HOLD_RATIO = 0.95
TO_MODEL_RATIO = 0.8
#: a switch needs the difference of the two mean |e| to exceed this many standard errors of the
#: per-probe differences (one-sided, about 98 % at 2)
SIGNIFICANCE = 2.0
#: probe-to-probe steps kept for the resolution estimate (and probes for the noise bound)
STEPS_KEPT = 256
#: a quantised signal: at least this many non-zero steps, each within this fraction of a whole
#: multiple of the smallest one
MIN_STEPS_FOR_RESOLUTION = 6
MULTIPLE_TOLERANCE = 0.08
#: share of unchanged probe-to-probe steps from which the signal is called plateau-like
PLATEAU_SHARE = 0.3
#: probes' second differences before they bound the configured noise (the bound's spread at
#: this count: see noise_bound)
MIN_TRIPLES_FOR_NOISE = 16
#: E|n| / std for Gaussian n
_ABS_PER_STD = math.sqrt(2.0 / math.pi)


def probe_totals(measured: Mapping[str, Any], applied: Mapping[str, Any]) -> dict[str, float]:
    """Total error per probed component: the residual the probe saw plus the compensation in
    effect (non-finite residual = not probed; non-finite applied = none)."""
    out = {}
    for c, v in measured.items():
        try:
            v = float(v)
        except (TypeError, ValueError):
            continue
        if not math.isfinite(v):
            continue
        a = applied.get(c, 0.0)
        a = float(a) if a is not None and math.isfinite(float(a)) else 0.0
        out[c] = v + a
    return out


def resolution(steps: Iterable[float]) -> float:
    """The quantisation step of a signal from its probe-to-probe steps: the smallest non-zero
    |step| when every non-zero step is a whole multiple of it (within MULTIPLE_TOLERANCE), and
    there are at least MIN_STEPS_FOR_RESOLUTION of them; NaN otherwise (a continuous signal)."""
    s = np.abs(np.asarray([x for x in steps if math.isfinite(x)], float))
    if s.size == 0:
        return math.nan
    nz = s[s > 1e-9 * max(1.0, float(s.max()))]
    if nz.size < MIN_STEPS_FOR_RESOLUTION:
        return math.nan
    q = float(nz.min())
    r = nz / q
    return q if float(np.max(np.abs(r - np.round(r)))) <= MULTIPLE_TOLERANCE else math.nan


def noise_bound(probes: Iterable[tuple[float, float]]) -> float:
    """An upper bound of the probe noise std from probed values (t, value): each probe's distance
    from the line through its neighbours, normalised to the noise it carries (1 + a^2 + b^2 times
    the noise variance); its mean square over the triples, raised to a one-sided upper bound of
    the chi-square's spread (two standard deviations). A drift that is not linear over two
    intervals only raises it. NaN with fewer than MIN_TRIPLES_FOR_NOISE triples."""
    p = np.asarray(list(probes), float).reshape(-1, 2)
    n = p.shape[0] - 2
    if n < MIN_TRIPLES_FOR_NOISE:
        return math.nan
    t, v = p[:, 0], p[:, 1]
    span = t[2:] - t[:-2]
    ok = span > 0
    a = np.where(ok, (t[2:] - t[1:-1]) / np.where(ok, span, 1.0), 0.5)
    b = 1.0 - a
    r = v[1:-1] - (a * v[:-2] + b * v[2:])
    z2 = r ** 2 / (1.0 + a ** 2 + b ** 2)
    return math.sqrt(float(np.mean(z2)) / (1.0 - 2.0 * math.sqrt(2.0 / n)))


def window_scores(scores: Iterable[tuple[float, float, float]], noise: float,
                  horizon_s: float = 0.0) -> tuple[float, float, float]:
    """(model, holding, standard error of their difference) from scored probes (|P1 - M|,
    |P1 - P0|, interval s) with probe noise std ``noise``: interval-mean |error| of each
    against the truth at the horizon (module docstring)."""
    s = np.asarray(list(scores), float).reshape(-1, 3)
    if s.shape[0] == 0:
        return math.nan, math.nan, math.nan
    dt = np.maximum(s[:, 2], 1e-9)
    w = np.sqrt(max(float(dt.max()), horizon_s) / dt)
    n_abs = _ABS_PER_STD * noise
    model = math.sqrt(max(float(np.mean(s[:, 0])) ** 2 - n_abs ** 2, 0.0))
    step = float(np.mean(s[:, 1] * w))
    drift = math.sqrt(max(step ** 2 - (math.sqrt(2.0) * n_abs * float(np.mean(w))) ** 2, 0.0))
    hold = math.sqrt((drift / 2.0) ** 2 + n_abs ** 2)
    d = s[:, 0] - s[:, 1] * w / 2.0
    se = float(np.std(d, ddof=1)) / math.sqrt(d.size) if d.size > 1 else math.inf
    return model, hold, se


class _Component:
    """The fall-back's state of one component."""

    def __init__(self, mode: str, noise: float):
        self.mode = mode
        self.noise = float(noise)                         # configured probe noise std (upper bound)
        self.last_total: float | None = None
        self.t_probe: float | None = None
        self.pending: tuple[float, float] | None = None   # (t, model prediction) since the last probe
        self.scores: deque = deque(maxlen=WINDOW)         # (model |P1-M|, hold |P1-P0|, interval s)
        self.switches = 0
        self.steps: deque = deque(maxlen=STEPS_KEPT)      # probe-to-probe steps of the total error
        self.probes: deque = deque(maxlen=STEPS_KEPT)     # (t, total) for the noise bound
        self.unchanged = 0
        self.n_steps = 0
        self.sigma = float(noise)                         # noise std the score uses (updated per probe)
        self.stale = False                                # hold mode, but the probe is older than its score covers

    def effective_noise(self) -> float:
        """The configured noise, capped by what the probes allow: half the mean square of the
        probe-to-probe steps (a drift only adds) and the second differences' bound; none on a
        quantised signal."""
        if math.isfinite(resolution(self.steps)):
            return 0.0
        bounds = [self.noise, noise_bound(self.probes)]
        if len(self.steps) >= MIN_SCORED:
            bounds.append(math.sqrt(float(np.mean(np.square(self.steps))) / 2.0))
        return min(b for b in bounds if math.isfinite(b))

    def evaluate(self, horizon_s: float = 0.0) -> tuple[float, float, float]:
        return window_scores(self.scores, self.sigma, horizon_s)

    def ratio(self, horizon_s: float = 0.0) -> float:
        m, h, _ = self.evaluate(horizon_s)
        if not math.isfinite(m):
            return math.nan
        if h <= 0.0:
            return math.inf if m > 0.0 else 1.0
        return m / h

    def covered_s(self, horizon_s: float) -> float:
        """The longest interval the score speaks for."""
        return max([horizon_s] + [s[2] for s in self.scores])

    def to_state(self) -> dict:
        return {"mode": self.mode, "last_total": self.last_total, "t_probe": self.t_probe,
                "pending": None if self.pending is None else list(self.pending), "score_form": "step",
                "scores": [list(s) for s in self.scores], "switches": self.switches, "steps": list(self.steps),
                "probes": [list(p) for p in self.probes], "unchanged": self.unchanged, "n_steps": self.n_steps}

    @classmethod
    def from_state(cls, state: Mapping[str, Any], noise: float) -> "_Component":
        if state.get("mode") not in (MODE_MODEL, MODE_HOLD):
            raise ValueError(f"hold_fallback state: 'mode' {state.get('mode')!r} is not 'model' or 'hold'")
        c = cls(state["mode"], noise)
        c.last_total, c.t_probe = state["last_total"], state["t_probe"]
        c.pending = None if state["pending"] is None else (float(state["pending"][0]), float(state["pending"][1]))
        half = state.get("score_form") != "step"          # older states kept holding's |step| / 2
        c.scores.extend((float(s[0]), float(s[1]) * (2.0 if half else 1.0), float(s[2])) for s in state["scores"])
        c.switches, c.unchanged, c.n_steps = int(state["switches"]), int(state["unchanged"]), int(state["n_steps"])
        c.steps.extend(float(x) for x in state["steps"])
        c.probes.extend((float(p[0]), float(p[1])) for p in state.get("probes", []))
        c.sigma = c.effective_noise()
        return c


class HoldFallback:
    """Per-component choice between the model's prediction and its last probe (module docstring).
    ``enabled`` False: the model's output passes unchanged (scores and detection still run).
    ``noise_std``: probe noise std per component (default Table 5.4 by the component's name)."""

    def __init__(self, components: Iterable[str], enabled: bool = True, trusted: bool = False,
                 horizon_s: float = 0.0, noise_std: Mapping[str, float] | None = None):
        if not (isinstance(horizon_s, (int, float)) and horizon_s >= 0 and not math.isnan(horizon_s)):
            raise ValueError(f"hold fall-back: horizon_s {horizon_s!r} must be a number >= 0")
        names = list(components)
        noise = {**table_5_4_noise(names), **dict(noise_std or {})}
        for c in names:
            v = noise[c]
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"hold fall-back: noise_std of '{c}' {v!r} must be a finite number >= 0")
        self.enabled = bool(enabled)
        #: the model's regular probing interval (s; 0 or inf: the window's longest interval)
        self.horizon_s = float(horizon_s) if math.isfinite(horizon_s) else 0.0
        self.components = {c: _Component(MODE_MODEL if trusted else MODE_HOLD, noise[c]) for c in names}
        #: started from a prior or a pretrained model (model mode first; it can still switch)
        self.trusted = bool(trusted)

    def trust(self) -> None:
        """The model starts from a prior or a pretrained model: model mode first. The score
        compares like with like (module docstring), so it falls back only where holding is
        measurably better."""
        self.trusted = True
        for comp in self.components.values():
            comp.mode = MODE_MODEL

    def mode(self, component: str) -> str:
        return self.components[component].mode

    def _stale(self, comp: _Component, t_s: float) -> bool:
        """Holding a probe older than its score covers: the model is expected to be better."""
        if comp.t_probe is None:
            return False
        age = float(t_s) - comp.t_probe
        covered = comp.covered_s(self.horizon_s)
        if age <= covered:
            return False
        if not comp.scores:
            return True
        m, h, _ = window_scores(comp.scores, comp.sigma, age)
        return m < TO_MODEL_RATIO * h

    def output(self, t_s: float, values: Mapping[str, float], has_prediction: bool) -> dict[str, float]:
        """The compensation from the model's ``values`` at ``t_s``: each component's model value
        or, in hold mode, its last probe (unless it is older than its score covers and the model
        is expected better). ``has_prediction`` False (a calibration phase): the last probe (0
        before any), not scored. A model value is remembered as the prediction the next probe
        scores. Disabled: the model's values unchanged."""
        out = dict(values)
        for c, comp in self.components.items():
            v = values.get(c, math.nan)
            if has_prediction and math.isfinite(v):
                comp.pending = (float(t_s), float(v))
            if not self.enabled or comp.last_total is None:
                continue
            comp.stale = comp.mode == MODE_HOLD and has_prediction and self._stale(comp, t_s)
            if not has_prediction or not math.isfinite(v):
                out[c] = comp.last_total
            elif comp.mode == MODE_HOLD and not comp.stale:
                out[c] = comp.last_total
        return out

    def observe(self, t_s: float, totals: Mapping[str, float]) -> None:
        """A probe measured ``totals`` (total error per component) at ``t_s``: score the model's
        prediction made before it against the previous probe, switch mode, remember the probe."""
        for c, total in totals.items():
            comp = self.components.get(c)
            if comp is None or not math.isfinite(total):
                continue
            if comp.last_total is not None:
                step = total - comp.last_total
                comp.n_steps += 1
                comp.unchanged += int(abs(step) <= 1e-9 * max(1.0, abs(total)))
                comp.steps.append(step)
            comp.probes.append((float(t_s), float(total)))
            comp.sigma = comp.effective_noise()
            if comp.last_total is not None and comp.pending is not None and comp.t_probe is not None \
                    and comp.pending[0] >= comp.t_probe:
                dt = max(float(t_s) - comp.t_probe, 1e-9)
                comp.scores.append((abs(total - comp.pending[1]), abs(total - comp.last_total), dt))
                self._decide(comp, self.horizon_s, MODE_MODEL if self.trusted else MODE_HOLD)
            comp.last_total, comp.t_probe = float(total), float(t_s)
            comp.pending = None

    @staticmethod
    def _decide(comp: _Component, horizon_s: float = 0.0, start_mode: str = MODE_HOLD) -> None:
        """Switch on the ratio with hysteresis; leaving the start mode (hold from zero, the model
        from a prior) also needs the difference to be significant, returning to it does not."""
        if len(comp.scores) < MIN_SCORED:
            return
        m, h, se = comp.evaluate(horizon_s)
        r = m / h if h > 0 else (math.inf if m > 0 else 1.0)
        z = SIGNIFICANCE * se
        if comp.mode == MODE_MODEL and r > TO_HOLD_RATIO and (start_mode == MODE_HOLD or m - h > z):
            comp.mode, comp.switches = MODE_HOLD, comp.switches + 1
        elif comp.mode == MODE_HOLD and r < TO_MODEL_RATIO and (start_mode == MODE_MODEL or h - m > z):
            comp.mode, comp.switches = MODE_MODEL, comp.switches + 1

    def signal(self, component: str) -> dict[str, Any]:
        """What the probes say about the component's signal: resolution (NaN: continuous), share
        of unchanged probe-to-probe steps, the noise std the score uses, and the words for it."""
        comp = self.components[component]
        q = resolution(comp.steps)
        share = comp.unchanged / comp.n_steps if comp.n_steps else math.nan
        words = []
        if math.isfinite(q):
            words.append(f"quantised in {q:.3g} steps")
        if comp.n_steps >= MIN_STEPS_FOR_RESOLUTION and share >= PLATEAU_SHARE:
            words.append(f"plateau-like ({100 * share:.0f} % of probes unchanged)")
        return {"resolution": q, "unchanged_share": share, "noise_std": comp.sigma, "words": ", ".join(words)}

    def diagnostics(self) -> dict[str, dict[str, Any]]:
        """Per component: mode, the model/hold ratio over the window, scored probes, switches,
        the noise the score uses, and the signal's resolution and plateau share."""
        out = {}
        for c, comp in self.components.items():
            sig = self.signal(c)
            out[c] = {"mode": comp.mode if self.enabled else MODE_MODEL, "stale": comp.stale,
                      "ratio_to_hold": comp.ratio(self.horizon_s),
                      "scored_probes": len(comp.scores), "switches": comp.switches, "noise_std": sig["noise_std"],
                      "resolution": sig["resolution"], "unchanged_share": sig["unchanged_share"],
                      "signal": sig["words"]}
        return out

    def note(self) -> str:
        """One line for the model's status message: which components hold and why, and what the
        probes show of quantised or plateau-like signals ("" when there is nothing to say)."""
        parts = []
        if self.enabled:
            held = [(c, comp.ratio(self.horizon_s), len(comp.scores)) for c, comp in self.components.items()
                    if comp.mode == MODE_HOLD and not comp.stale]
            stale = [c for c, comp in self.components.items() if comp.mode == MODE_HOLD and comp.stale]
            if stale:
                parts.append("the model's output on " + ", ".join(stale) + " (its last probe is older than "
                             "the score covers)")
            if held:
                parts.append("holding the last probe on " + ", ".join(
                    f"{c} (model/hold {r:.2f} over {n} probes)" if n else f"{c} (model not scored yet)"
                    for c, r, n in held))
        for c in self.components:
            words = self.signal(c)["words"]
            if words:
                parts.append(f"{c} {words}")
        return ("; " + "; ".join(parts)) if parts else ""

    def to_state(self) -> dict:
        return {"enabled": self.enabled, "trusted": self.trusted,
                "components": {c: comp.to_state() for c, comp in self.components.items()}}

    @classmethod
    def from_state(cls, state: Mapping[str, Any] | None, components: Iterable[str], enabled: bool,
                   horizon_s: float = 0.0, noise_std: Mapping[str, float] | None = None) -> "HoldFallback":
        """The fall-back of a saved model; a state saved without one (None) starts in model mode
        (the model was running before it existed)."""
        names = list(components)
        if state is None:
            return cls(names, enabled, trusted=True, horizon_s=horizon_s, noise_std=noise_std)
        hf = cls(names, enabled, horizon_s=horizon_s, noise_std=noise_std)
        hf.trusted = bool(state.get("trusted", state.get("keeps_model", False)))
        saved = state.get("components") or {}
        for c in names:
            if c in saved:
                hf.components[c] = _Component.from_state(saved[c], hf.components[c].noise)
        return hf
