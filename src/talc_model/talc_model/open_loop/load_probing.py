"""Probing after a load change the CNC knows, within an average budget (adaptive mode of ``evaluate``).

A step of a machine-input column (spindle speed, coolant, door: whatever inputs the recording
has) changes the heat flows, and the model is least sure after it; the twin's TALC has the same
rule for coolant switches (``switch_probe_delay_min``). So a step makes a probing due
``delay_min`` later. The budget is a **token bucket**: it fills at ``max_probes_per_h`` per hour
up to ``depth`` probings and holds ``credit`` (one, or none) probing at the start of the probing clock; every probing
(scheduled, asked for by the model's predicted change, or due after a step) spends one token and
none happens without one, so after the clock starts the probings never exceed
``credit + max_probes_per_h x elapsed hours`` (credit 0: never more than one per hour on average). The regular probings (the model's predicted change, as
without the rule) spend only a full bucket, so ``depth - 1`` probings stay saved for the steps.
No inputs, or no step, and the rule never fires.

:class:`LoadBucketProbing` (kind ``load_bucket``) is the same rule around any streaming adaptive
model: the wrapped model's own probing wish is the "model asks", the bucket governs every
probing once the wrapped model has left its calibration phase. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from talc_model.adaptive_model import (PHASE_CALIBRATION, AdaptiveModel, ModelStatusData, make_model,
                                       model_from_state, register_model)

#: a machine input has stepped once it moved this share of its training range from its level at
#: its last step (a slow ramp counts once it has moved as far)
STEP_FRACTION = 0.1
#: the probing is due this long after a step (minutes): candidates of the walk-forward
DELAYS_MIN = (5.0, 10.0, 20.0, 30.0)
#: the bucket's depth in probings (1: no probing is saved, the credit at the clock's start only)
DEPTHS = (1.0, 2.0, 3.0)


class LoadProbingError(ValueError):
    """Bad input to the load-change rule; the message names the argument and value."""


class StepDetector:
    """One machine input's steps: a reading more than ``size`` away from the level at the last
    step (the first finite reading sets the level) is a step and the new level."""

    def __init__(self, size: float, level: float | None = None):
        self.size = float(size)
        self.level = level

    def update(self, value: float) -> bool:
        if value is None or not math.isfinite(value):
            return False
        if self.level is None:
            self.level = value
        if abs(value - self.level) > self.size:
            self.level = value
            return True
        return False


@dataclass
class TokenBucket:
    """Fills at ``rate_per_h`` per hour up to ``depth`` tokens; a probing spends one."""

    rate_per_h: float
    depth: float
    tokens: float
    last_t: float

    def refill(self, t_s: float) -> None:
        self.tokens = min(self.depth, self.tokens + self.rate_per_h * (t_s - self.last_t) / 3600.0)
        self.last_t = t_s

    def full(self) -> bool:
        return self.tokens >= self.depth - 1e-9


def bucket_decision(bucket: TokenBucket, t_s: float, since_s: float, pending_s: float | None, min_gap_s: float,
                    probe_every_s: float, asks: Callable[[], bool]) -> tuple[bool, bool, bool]:
    """(probe, due after a step, scheduled) at ``t_s``, ``since_s`` after the end of the last
    cycle: none without a token; due once ``pending_s`` passed, scheduled every ``probe_every_s``,
    and a full bucket also pays for the model's own wish (``asks``, evaluated only then)."""
    if bucket.tokens < 1.0 or since_s < 0:
        return False, False, False
    due = pending_s is not None and t_s >= pending_s and since_s >= min_gap_s
    scheduled = since_s >= probe_every_s
    surplus = bucket.full() and since_s >= min_gap_s and asks()
    return bool(due or scheduled or surplus), bool(due), bool(scheduled)


def input_steps(inputs: np.ndarray | None, n_train: int, fraction: float = STEP_FRACTION) -> np.ndarray:
    """Rows at which any machine input stepped: it moved more than ``fraction`` of its range on
    the training rows (rows < ``n_train``) away from its level at its previous step. A column
    constant (or not finite) on the training rows has no steps; no inputs: no steps."""
    if not (math.isfinite(fraction) and fraction > 0):
        raise LoadProbingError(f"fraction: {fraction!r} must be a finite number > 0")
    if inputs is None or np.asarray(inputs).size == 0:
        return np.zeros(0, int)
    u = np.asarray(inputs, float)
    u = u[:, None] if u.ndim == 1 else u
    rows: set[int] = set()
    for j in range(u.shape[1]):
        col = u[:, j]
        train = col[:n_train][np.isfinite(col[:n_train])]
        span = float(train.max() - train.min()) if train.size else 0.0
        if not (math.isfinite(span) and span > 0):
            continue
        detector = StepDetector(fraction * span)
        rows.update(r for r, v in enumerate(col) if detector.update(v))
    return np.asarray(sorted(rows), int)


def bucket_schedule(time_s: np.ndarray, start: int, clock0_s: float, steps: np.ndarray, rate_per_h: float,
                    depth: float, delay_s: float, min_gap_s: float, probe_every_s: float, probe_duration_s: float,
                    asks: Callable[[int, int], bool], credit: float = 1.0) -> tuple[list[int], list[int], list[int]]:
    """Probe rows >= ``start`` (nothing before ``clock0_s``), the rows not scheduled (asked for
    by ``asks(row, last_probe_row)`` or due after a step) and those due after a step. Reads the
    time, the step rows and ``asks`` only (never a displacement)."""
    if not (math.isfinite(depth) and depth >= 1):
        raise LoadProbingError(f"depth: {depth!r} must be a finite number >= 1")
    if not (math.isfinite(credit) and 0 <= credit <= 1):
        raise LoadProbingError(f"credit: {credit!r} must be in [0, 1]")
    if not (math.isfinite(delay_s) and delay_s >= 0):
        raise LoadProbingError(f"delay_s: {delay_s!r} must be a finite number >= 0")
    t = np.asarray(time_s, float)
    bucket = TokenBucket(rate_per_h, depth, float(credit), clock0_s)   # it holds the credit when the clock starts
    last_end, last_row = clock0_s, start - 1    # the calibration phase ends with a measurement
    steps = np.asarray(steps, int)
    before = steps[(steps < start) & (t[np.minimum(steps, len(t) - 1)] + delay_s > t[start - 1])]
    pending = float(t[before[0]] + delay_s) if before.size else None   # a step in the last minutes of training
    step_rows = set(int(r) for r in steps[steps >= start])
    rows, asked, load = [], [], []
    for r in range(start, len(t)):
        if r in step_rows and pending is None:
            pending = float(t[r] + delay_s)
        if t[r] < clock0_s:
            continue
        bucket.refill(t[r])
        probe, due, scheduled = bucket_decision(bucket, t[r], t[r] - last_end, pending, min_gap_s, probe_every_s,
                                                lambda: asks(r, last_row))
        if probe:
            rows.append(r)
            if due:
                load.append(r)
            if due or not scheduled:
                asked.append(r)
            bucket.tokens -= 1.0
            if due or (pending is not None and t[r] >= pending):
                pending = None                  # a probing before the due time leaves it due
            last_end, last_row = t[r] + probe_duration_s, r
    return rows, asked, load


def within_bucket_bound(time_s: np.ndarray, rows: list[int], clock0_s: float, rate_per_h: float,
                        credit: float = 1.0) -> bool:
    """Whether every prefix of the probings stays within credit + rate x the hours since the clock started."""
    return all(i + 1 <= credit + rate_per_h * (time_s[r] - clock0_s) / 3600.0 + 1e-9 for i, r in enumerate(rows))


#: configuration keys of :class:`LoadBucketProbing` and their defaults
BUCKET_DEFAULTS: dict[str, Any] = {
    "model_kind": "talc",            # the wrapped model, built by make_model
    "model_config": {},
    "step_sizes": {},                # machine-state key -> change that is a step (none: the rule never fires)
    "delay_s": 600.0,                # a probing is due this long after a step
    "rate_per_h": 1.0,               # the bucket's average budget
    "depth": 2.0,
    "credit": 1.0,
    "min_gap_s": 600.0,              # after the end of the previous cycle
    "probe_every_s": 7200.0,         # the regular schedule
    "probe_duration_s": 95.0,
}


def _checked_bucket_config(config: Mapping[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(config) - set(BUCKET_DEFAULTS))
    if unknown:
        raise LoadProbingError(f"LoadBucketProbing config: unknown key {unknown[0]!r} (known: {sorted(BUCKET_DEFAULTS)})")
    cfg = {**BUCKET_DEFAULTS, **config}
    cfg["model_config"] = dict(cfg["model_config"])
    cfg["step_sizes"] = {str(k): float(v) for k, v in dict(cfg["step_sizes"]).items()}
    for k, v in cfg["step_sizes"].items():
        if not (math.isfinite(v) and v > 0):
            raise LoadProbingError(f"step_sizes[{k!r}]: {v!r} must be a finite number > 0")
    for k in ("rate_per_h", "probe_every_s", "probe_duration_s"):
        if not (isinstance(cfg[k], (int, float)) and math.isfinite(cfg[k]) and cfg[k] > 0):
            raise LoadProbingError(f"{k}: {cfg[k]!r} must be a finite number > 0")
    for k in ("delay_s", "min_gap_s"):
        if not (isinstance(cfg[k], (int, float)) and math.isfinite(cfg[k]) and cfg[k] >= 0):
            raise LoadProbingError(f"{k}: {cfg[k]!r} must be a finite number >= 0")
    if not (isinstance(cfg["depth"], (int, float)) and math.isfinite(cfg["depth"]) and cfg["depth"] >= 1):
        raise LoadProbingError(f"depth: {cfg['depth']!r} must be a finite number >= 1")
    if not (isinstance(cfg["credit"], (int, float)) and math.isfinite(cfg["credit"]) and 0 <= cfg["credit"] <= 1):
        raise LoadProbingError(f"credit: {cfg['credit']!r} must be in [0, 1]")
    return cfg


@register_model("load_bucket")
class LoadBucketProbing:
    """An AdaptiveModel that probes ``delay_s`` after a machine-input step, on the regular schedule
    and, with a full bucket, when the wrapped model asks; every probing after the wrapped model's
    calibration spends a token, so they never exceed ``credit + rate_per_h`` x the hours since."""

    def __init__(self, model: AdaptiveModel, config: Mapping[str, Any] | None = None):
        cfg = _checked_bucket_config(dict(config or {}))
        self.model = model
        self.config = cfg
        self.component_names = list(model.component_names)
        self.detectors = {k: StepDetector(v) for k, v in cfg["step_sizes"].items()}
        self.bucket: TokenBucket | None = None       # None until the wrapped model has calibrated
        self.last_end_s = -math.inf
        self.pending_s: float | None = None
        self.due = False                             # the last probe_due was a probing due after a step
        self.load_probings = 0

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> "LoadBucketProbing":
        cfg = _checked_bucket_config(dict(config))
        return cls(make_model(cfg["model_kind"], cfg["model_config"]), cfg)

    def _clock(self, t_s: float) -> TokenBucket | None:
        """The bucket, started (holding the credit) when the wrapped model leaves calibration."""
        if self.bucket is None and self.model.status(t_s).phase != PHASE_CALIBRATION:
            self.bucket = TokenBucket(self.config["rate_per_h"], self.config["depth"], float(self.config["credit"]), t_s)
            self.last_end_s = t_s
        return self.bucket

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float], machine_state: Mapping[str, float]) -> None:
        self.model.update_inputs(t_s, temperatures, machine_state)
        stepped = [d.update(float(machine_state.get(k, math.nan))) for k, d in self.detectors.items()]
        if any(stepped) and self.pending_s is None:
            self.pending_s = t_s + self.config["delay_s"]
        if self.bucket is None and self.pending_s is not None and t_s >= self.pending_s:
            self.pending_s = None                    # due during calibration: that phase probes anyway

    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]:
        return self.model.predict(t_s)

    def probe_due(self, t_s: float) -> bool:
        own = self.model.probe_due(t_s)              # always asked: it sets the model's reason
        bucket = self._clock(t_s)
        if bucket is None:
            return own
        bucket.refill(t_s)
        probe, self.due, _ = bucket_decision(bucket, t_s, t_s - self.last_end_s, self.pending_s,
                                             self.config["min_gap_s"], self.config["probe_every_s"], lambda: own)
        return probe

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        self._spend(t_s)
        self.model.add_measurement(t_s, measured, applied_compensation)

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        self._spend(t_s)
        self.model.add_failed_measurement(t_s, reason)

    def _spend(self, t_s: float) -> None:
        if self.bucket is None:
            return
        self.bucket.refill(t_s)
        self.bucket.tokens -= 1.0
        if self.due:
            self.load_probings += 1
        if self.pending_s is not None and t_s >= self.pending_s:
            self.pending_s = None
        self.due = False
        self.last_end_s = t_s + self.config["probe_duration_s"]

    def status(self, t_s: float) -> ModelStatusData:
        st = self.model.status(t_s)
        if self.bucket is not None and self.pending_s is not None:
            st.next_probing_due_s = min(st.next_probing_due_s, self.pending_s)
        return st

    def to_state(self) -> dict[str, Any]:
        return {"kind": self.kind, "config": self.config, "model": self.model.to_state(),
                "levels": {k: d.level for k, d in self.detectors.items()},
                "bucket": None if self.bucket is None else [self.bucket.tokens, self.bucket.last_t],
                "last_end_s": None if self.bucket is None else self.last_end_s, "pending_s": self.pending_s,
                "due": self.due, "load_probings": self.load_probings}

    @classmethod
    def from_state(cls, state: dict) -> "LoadBucketProbing":
        try:
            w = cls(model_from_state(state["model"]), state["config"])
            for k, level in state["levels"].items():
                w.detectors[k].level = level
            if state["bucket"] is not None:
                w.bucket = TokenBucket(w.config["rate_per_h"], w.config["depth"], *state["bucket"])
                w.last_end_s = float(state["last_end_s"])
            w.pending_s, w.due, w.load_probings = state["pending_s"], bool(state["due"]), int(state["load_probings"])
        except KeyError as exc:
            raise LoadProbingError(f"LoadBucketProbing state: missing key {exc}") from None
        return w
