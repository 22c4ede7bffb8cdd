"""A clock offset between a recording's inputs and its measured channels, found and removed
before the search.

A recorder that stamps the machine state and the readings on different clocks shifts every
measured channel by one common time s against the inputs: measured(t) = true(t + s). No word
of the vocabulary is a common shift (``time_lag`` delays one reading through a first-order
lag); left in, the residual is about s times the twin's rate on every channel, and the search
answers rate terms. The offset is estimated from the twin as given: its outputs shifted by s
(linear interpolation of the smooth noise-free outputs) against the measured channels on the
training window, on a grid of quarter steps within +-``MAX_STEPS`` steps refined by a parabola.
Each channel scores its sum of squares with its mean removed (a bias does not move with s);
the channels are combined by the sum of the logs, so each channel has one vote and a large
missing effect on one channel cannot pull the common shift.

The shift is removed (every sensor and error column re-sampled at t - s) only if it is
*common and confirmed*: at least ``MIN_IMPROVED`` of the channels that respond to a shift
improve at s, at least ``MIN_SHARE`` of the responding ones, and the held-out window (never
used for the estimate) does not get worse (a window at rest hardly responds to a shift). A lag of one sensor improves one channel only and
stays for the search.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_comp_common.recording_csv import Recording, column_kind

MAX_STEPS = 2.5           # the largest offset looked for, in recording steps
GRID_STEPS = 0.25         # grid of the search, in steps
RESPONSIVE = 0.02         # a channel whose sum of squares changes less than this over the grid does not vote
MIN_IMPROVED = 3
MIN_SHARE = 0.75
MIN_STEPS = 0.2           # a smaller estimate is no evidence of an offset
HOLDOUT_TOLERANCE_PCT = 1.0   # the held-out window must not get worse by more than this


@dataclass
class ClockOffset:
    shift_s: float                 # estimated offset (measured(t) = true(t + shift_s)), 0 if none
    step_s: float
    applied: bool
    responsive: int                # channels whose fit responds to a shift
    improved: int                  # of those, improved at shift_s (training window)
    worse: int
    holdout_change_pct: float      # change of the summed log held-out sums of squares, as a fall in %
    reason: str

    def as_dict(self) -> dict:
        return {"shift_s": self.shift_s, "steps": self.shift_s / self.step_s if self.step_s else 0.0,
                "applied": self.applied, "channels_responsive": self.responsive,
                "channels_improved": self.improved, "channels_worse": self.worse,
                "holdout_improvement_pct": self.holdout_change_pct, "reason": self.reason}


def _sse(t: np.ndarray, meas: np.ndarray, valid: np.ndarray, y: np.ndarray, s: float, sl: slice) -> np.ndarray:
    """Per channel: sum of squares (mean removed) of measured - y(t + s) on ``sl``."""
    out = np.empty(len(meas))
    for i in range(len(meas)):
        ys = np.interp(t[sl] + s, t, y[i])
        r = (meas[i, sl] - ys)[valid[i, sl]]
        out[i] = float(np.sum((r - r.mean()) ** 2)) if r.size > 1 else 0.0
    return out


def estimate(t: np.ndarray, meas: np.ndarray, valid: np.ndarray, y: np.ndarray, n_train: int) -> ClockOffset:
    """The common offset of the measured channels ``meas`` (channels x time, ``valid`` where
    read) against the twin's outputs ``y``; see the module docstring for the rule."""
    t = np.asarray(t, dtype=float)
    step = float(np.median(np.diff(t)))
    tr = slice(0, n_train)
    grid = np.arange(-MAX_STEPS, MAX_STEPS + 1e-9, GRID_STEPS) * step
    sse = np.array([_sse(t, meas, valid, y, s, tr) for s in grid])      # (shifts, channels)
    i0 = int(np.argmin(np.abs(grid)))
    base = np.maximum(sse[i0], 1e-300)
    resp = np.max(np.abs(sse - base) / base, axis=0) > RESPONSIVE
    if resp.sum() < MIN_IMPROVED:
        return ClockOffset(0.0, step, False, int(resp.sum()), 0, 0, 0.0, "too few channels respond to a shift")
    obj = np.log(np.maximum(sse[:, resp], 1e-300)).sum(axis=1)
    k = int(np.argmin(obj))
    s = float(grid[k])
    if 0 < k < len(grid) - 1:
        a, b, c = obj[k - 1], obj[k], obj[k + 1]
        den = a - 2 * b + c
        if den > 0:
            s += 0.5 * (a - c) / den * (grid[1] - grid[0])
    if abs(s) < MIN_STEPS * step:
        return ClockOffset(0.0, step, False, int(resp.sum()), 0, 0, 0.0, "no shift fits better than none")
    at = _sse(t, meas, valid, y, s, tr)[resp]
    improved = int(np.sum(at < base[resp] * (1 - 0.5 * RESPONSIVE)))
    worse = int(np.sum(at > base[resp] * (1 + 0.5 * RESPONSIVE)))
    ho = slice(n_train, t.size)
    h0 = np.maximum(_sse(t, meas, valid, y, 0.0, ho)[resp], 1e-300)
    h1 = np.maximum(_sse(t, meas, valid, y, s, ho)[resp], 1e-300)
    ho_pct = float(100.0 * (1.0 - np.exp(np.mean(np.log(h1 / h0)))))
    ok = (improved >= MIN_IMPROVED and improved >= MIN_SHARE * resp.sum()
          and ho_pct > -HOLDOUT_TOLERANCE_PCT)
    reason = ("common to the channels and confirmed on held-out data" if ok else
              "not common to the channels" if improved < MIN_SHARE * resp.sum() or improved < MIN_IMPROVED
              else "not confirmed on held-out data")
    return ClockOffset(s if ok else 0.0, step, ok, int(resp.sum()), improved, worse, ho_pct, reason)


def realign(rec: Recording, shift_s: float) -> Recording:
    """The recording with every sensor and error column re-sampled at t - ``shift_s`` (the
    inputs' clock); a reading outside the recorded span, or next to a missing one, is missing."""
    t = rec.time_s
    cols = {}
    for name, v in rec.columns.items():
        if column_kind(name) not in ("sensor", "error"):
            cols[name] = v
            continue
        x = np.asarray(v, dtype=float)
        ok = np.isfinite(x)
        if ok.sum() < 2:
            cols[name] = x
            continue
        y = np.interp(t - shift_s, t[ok], x[ok], left=np.nan, right=np.nan)
        near = np.interp(t - shift_s, t, ok.astype(float), left=0.0, right=0.0)
        cols[name] = np.where(near > 1.0 - 1e-9, y, np.nan)
    note = f"clock offset: measured channels re-sampled {shift_s:+.4g} s earlier (inputs' clock)"
    return Recording(t, cols, source=rec.source, warnings=list(rec.warnings) + [note])
