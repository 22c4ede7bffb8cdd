"""When a model's prediction is not worth more than its last probe: hold the probe (part of every model).

An adaptive model that predicts worse than holding its own last probe costs the machine accuracy
for nothing. :class:`HoldFallback` keeps, per component, a prequential (out-of-sample) score of
the model against the hold-last-probe predictor and switches the component's output between the
two with hysteresis:

- at every probe, BEFORE the model learns from it, the model's prediction made just before the
  probe (the last :meth:`output` call) and the previous probe's value are compared with the new
  probe's total error;
- the interval-average absolute error of each predictor is estimated from the probe: holding
  starts each interval exact and ends |step| off, so |step| / 2 (a linear drift, or a quantum
  step at a random instant, give that mean); the model's error at the end of the interval stands
  for the whole interval. That is conservative for a model that restarts from each probe (its
  error grows from near 0 too) and right for one whose error is stationary (the GP, a TALC
  observer with a small gain); a line from the model's first prediction after the probe to its
  last read low on a quantised signal (the update pulls the first prediction toward the probe,
  the model drifts away after: docs/talc.md). Mean absolute, not squared: on
  a quantised or plateau-like signal holding is exact most of the time and one step off the rest,
  which a mean square rates worse than a model's small errors everywhere although its mean error
  (what the evaluation and the parts see) is lower;
- holding's error grows with the time since the probe, the model's does not: a score taken over
  a short interval (a prior's check phase, a no-good phase probing every few minutes) would make
  holding look better than it is at the interval the model probes at otherwise. Each holding
  score is therefore scaled to the model's regular probing interval (``horizon_s``) or the
  longest interval of the window if that is longer, as a random walk grows (square root of
  the time: between probe noise, which does not grow, and a steady drift, which grows linearly);
- over the last ``window`` scored probes, ratio = mean |e| (model) / mean |e| (hold); a component in model
  mode holds once ratio > ``to_hold_ratio``, one in hold mode returns to the model once ratio <
  ``to_model_ratio`` (hysteresis), never before ``min_scored`` probes were scored.

A model in its calibration phase has no prediction yet and holds its last probe (the AGP and the
CD model did so already; TALC compensated nothing there, and now its calibration probes see the
held compensation and learn from the total error = residual + applied, as everywhere). A model started from a prior or a pretrained model keeps its model (the prior is what it has to
say; its score is kept and reported, see :meth:`HoldFallback.trust` for why it does not switch);
one started from zero starts holding and earns the model mode. Quantised or plateau-like
error signals are detected from the probed values (resolution: the smallest non-zero step between
probes when every step is a whole multiple of it) and said in :meth:`note`. No rclpy here.
docs/talc.md, "Never clearly worse than holding".
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Iterable, Mapping

import numpy as np

MODE_MODEL = "model"
MODE_HOLD = "hold"
#: scored probes a decision looks back on
WINDOW = 8
#: scored probes before the first switch
MIN_SCORED = 3
#: model mode -> hold above this ratio of interval mean |e|; hold -> model below the second
TO_HOLD_RATIO = 0.95
TO_MODEL_RATIO = 0.8
#: probe-to-probe steps kept for the resolution estimate
STEPS_KEPT = 256
#: a quantised signal: at least this many non-zero steps, each within this fraction of a whole
#: multiple of the smallest one
MIN_STEPS_FOR_RESOLUTION = 6
MULTIPLE_TOLERANCE = 0.08
#: share of unchanged probe-to-probe steps from which the signal is called plateau-like
PLATEAU_SHARE = 0.3


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


class _Component:
    """The fall-back's state of one component."""

    def __init__(self, mode: str):
        self.mode = mode
        self.last_total: float | None = None
        self.t_probe: float | None = None
        self.pending: tuple[float, float] | None = None   # (t, model prediction) since the last probe
        self.scores: deque = deque(maxlen=WINDOW)         # (model |e|, hold mean |e|, interval s)
        self.switches = 0
        self.steps: deque = deque(maxlen=STEPS_KEPT)      # probe-to-probe steps of the total error
        self.unchanged = 0
        self.n_steps = 0

    def ratio(self, horizon_s: float = 0.0) -> float:
        if not self.scores:
            return math.nan
        longest = max(max(s[2] for s in self.scores), horizon_s)
        m = sum(s[0] for s in self.scores)
        h = sum(s[1] * math.sqrt(longest / s[2]) for s in self.scores)
        if h <= 0.0:
            return math.inf if m > 0.0 else 1.0
        return m / h

    def to_state(self) -> dict:
        return {"mode": self.mode, "last_total": self.last_total, "t_probe": self.t_probe,
                "pending": None if self.pending is None else list(self.pending),
                "scores": [list(s) for s in self.scores], "switches": self.switches, "steps": list(self.steps),
                "unchanged": self.unchanged, "n_steps": self.n_steps}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "_Component":
        if state.get("mode") not in (MODE_MODEL, MODE_HOLD):
            raise ValueError(f"hold_fallback state: 'mode' {state.get('mode')!r} is not 'model' or 'hold'")
        c = cls(state["mode"])
        c.last_total, c.t_probe = state["last_total"], state["t_probe"]
        c.pending = None if state["pending"] is None else (float(state["pending"][0]), float(state["pending"][1]))
        c.scores.extend(tuple(float(x) for x in s) for s in state["scores"])
        c.switches, c.unchanged, c.n_steps = int(state["switches"]), int(state["unchanged"]), int(state["n_steps"])
        c.steps.extend(float(x) for x in state["steps"])
        return c


class HoldFallback:
    """Per-component choice between the model's prediction and its last probe (module docstring).
    ``enabled`` False: the model's output passes unchanged (scores and detection still run)."""

    def __init__(self, components: Iterable[str], enabled: bool = True, trusted: bool = False,
                 horizon_s: float = 0.0):
        if not (isinstance(horizon_s, (int, float)) and horizon_s >= 0 and not math.isnan(horizon_s)):
            raise ValueError(f"hold fall-back: horizon_s {horizon_s!r} must be a number >= 0")
        self.enabled = bool(enabled)
        #: the model's regular probing interval (s; 0 or inf: the window's longest interval)
        self.horizon_s = float(horizon_s) if math.isfinite(horizon_s) else 0.0
        self.components = {c: _Component(MODE_MODEL if trusted else MODE_HOLD) for c in components}
        #: a model from a prior or a pretrained model: scored and reported, never switched to holding
        self.keeps_model = False

    def trust(self) -> None:
        """The model starts from a prior or a pretrained model: it keeps its model. Its score
        against holding is still kept and reported, but the score is biased towards holding by
        the probe noise where the drift between probes is small against it (the model's error at
        a probe carries one noise draw, holding's half step half of two): on the nmv5000 twin with
        the type's prior it turned a replay from 0.19 to 0.32 of probe-and-hold (docs/talc.md)."""
        self.keeps_model = True
        for comp in self.components.values():
            comp.mode = MODE_MODEL

    def mode(self, component: str) -> str:
        return self.components[component].mode

    def output(self, t_s: float, values: Mapping[str, float], has_prediction: bool) -> dict[str, float]:
        """The compensation from the model's ``values`` at ``t_s``: each component's model value
        or, in hold mode, its last probe. ``has_prediction`` False (a calibration phase): the last
        probe (0 before any), not scored. A model value is remembered as the prediction the next
        probe scores. Disabled: the model's values unchanged."""
        out = dict(values)
        for c, comp in self.components.items():
            v = values.get(c, math.nan)
            if has_prediction and math.isfinite(v):
                comp.pending = (float(t_s), float(v))
            if self.enabled and comp.last_total is not None and (not has_prediction or comp.mode == MODE_HOLD):
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
                if comp.pending is not None and comp.t_probe is not None and comp.pending[0] >= comp.t_probe:
                    dt = max(float(t_s) - comp.t_probe, 1e-9)
                    comp.scores.append((abs(total - comp.pending[1]), abs(step) / 2.0, dt))
                    self._decide(comp, self.horizon_s, self.keeps_model)
            comp.last_total, comp.t_probe = float(total), float(t_s)
            comp.pending = None

    @staticmethod
    def _decide(comp: _Component, horizon_s: float = 0.0, keeps_model: bool = False) -> None:
        if len(comp.scores) < MIN_SCORED:
            return
        r = comp.ratio(horizon_s)
        if comp.mode == MODE_MODEL and r > TO_HOLD_RATIO and not keeps_model:
            comp.mode, comp.switches = MODE_HOLD, comp.switches + 1
        elif comp.mode == MODE_HOLD and r < TO_MODEL_RATIO:
            comp.mode, comp.switches = MODE_MODEL, comp.switches + 1

    def signal(self, component: str) -> dict[str, Any]:
        """What the probes say about the component's signal: resolution (NaN: continuous), share
        of unchanged probe-to-probe steps, and the words for it."""
        comp = self.components[component]
        q = resolution(comp.steps)
        share = comp.unchanged / comp.n_steps if comp.n_steps else math.nan
        words = []
        if math.isfinite(q):
            words.append(f"quantised in {q:.3g} steps")
        if comp.n_steps >= MIN_STEPS_FOR_RESOLUTION and share >= PLATEAU_SHARE:
            words.append(f"plateau-like ({100 * share:.0f} % of probes unchanged)")
        return {"resolution": q, "unchanged_share": share, "words": ", ".join(words)}

    def diagnostics(self) -> dict[str, dict[str, Any]]:
        """Per component: mode, the model/hold ratio over the window, scored probes, switches,
        and the signal's resolution and plateau share."""
        out = {}
        for c, comp in self.components.items():
            sig = self.signal(c)
            out[c] = {"mode": comp.mode if self.enabled else MODE_MODEL, "ratio_to_hold": comp.ratio(self.horizon_s),
                      "scored_probes": len(comp.scores), "switches": comp.switches,
                      "resolution": sig["resolution"], "unchanged_share": sig["unchanged_share"],
                      "signal": sig["words"]}
        return out

    def note(self) -> str:
        """One line for the model's status message: which components hold and why, and what the
        probes show of quantised or plateau-like signals ("" when there is nothing to say)."""
        parts = []
        if self.enabled:
            held = [(c, comp.ratio(self.horizon_s), len(comp.scores)) for c, comp in self.components.items()
                    if comp.mode == MODE_HOLD]
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
        return {"enabled": self.enabled, "keeps_model": self.keeps_model,
                "components": {c: comp.to_state() for c, comp in self.components.items()}}

    @classmethod
    def from_state(cls, state: Mapping[str, Any] | None, components: Iterable[str], enabled: bool,
                   horizon_s: float = 0.0) -> "HoldFallback":
        """The fall-back of a saved model; a state saved without one (None) starts in model mode
        (the model was running before it existed)."""
        names = list(components)
        if state is None:
            return cls(names, enabled, trusted=True, horizon_s=horizon_s)
        hf = cls(names, enabled, horizon_s=horizon_s)
        hf.keeps_model = bool(state.get("keeps_model", False))
        saved = state.get("components") or {}
        for c in names:
            if c in saved:
                hf.components[c] = _Component.from_state(saved[c])
        return hf
