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
No inputs, or no step, and the rule never fires. Pure functions; no rclpy here.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

#: a machine input has stepped once it moved this share of its training range from its level at
#: its last step (a slow ramp counts once it has moved as far)
STEP_FRACTION = 0.1
#: the probing is due this long after a step (minutes): candidates of the walk-forward
DELAYS_MIN = (5.0, 10.0, 20.0, 30.0)
#: the bucket's depth in probings (1: no probing is saved, the credit at the clock's start only)
DEPTHS = (1.0, 2.0, 3.0)


class LoadProbingError(ValueError):
    """Bad input to the load-change rule; the message names the argument and value."""


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
        level = next((v for v in col if math.isfinite(v)), math.nan)
        for r, v in enumerate(col):
            if math.isfinite(v) and abs(v - level) > fraction * span:
                rows.add(r)
                level = v
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
    tokens, last_t = float(credit), clock0_s    # the bucket holds the credit when the clock starts
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
        tokens = min(depth, tokens + rate_per_h * (t[r] - last_t) / 3600.0)
        last_t = t[r]
        since = t[r] - last_end
        if tokens < 1.0 or since < 0:
            continue
        due = pending is not None and t[r] >= pending and since >= min_gap_s
        scheduled = since >= probe_every_s
        surplus = tokens >= depth - 1e-9 and since >= min_gap_s and asks(r, last_row)
        if due or scheduled or surplus:
            rows.append(r)
            if due:
                load.append(r)
            if due or not scheduled:
                asked.append(r)
            tokens -= 1.0
            if due or (pending is not None and t[r] >= pending):
                pending = None                  # a probing before the due time leaves it due
            last_end, last_row = t[r] + probe_duration_s, r
    return rows, asked, load


def within_bucket_bound(time_s: np.ndarray, rows: list[int], clock0_s: float, rate_per_h: float,
                        credit: float = 1.0) -> bool:
    """Whether every prefix of the probings stays within credit + rate x the hours since the clock started."""
    return all(i + 1 <= credit + rate_per_h * (time_s[r] - clock0_s) / 3600.0 + 1e-9 for i, r in enumerate(rows))
