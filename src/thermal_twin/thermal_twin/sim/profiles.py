"""Building blocks of scenarios: hall ambient, random speed programmes, on/off switching.

All functions are pure: they take the time grid and a ``numpy.random.Generator`` and return
arrays of values held over each step. Times in seconds, temperatures in degC.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

DAY_S = 86400.0


@dataclass(frozen=True)
class DoorDrop:
    """A hall-door opening: the ambient falls by ``depth`` within ``fall_s``, stays open for
    ``open_s``, then recovers with time constant ``recovery_s``; afterwards the hall
    fluctuates (std ``fluctuation``) for ``fluctuation_s``."""

    start_s: float
    depth: float = 3.0
    fall_s: float = 1500.0
    open_s: float = 1800.0
    recovery_s: float = 5400.0
    fluctuation: float = 0.4
    fluctuation_s: float = 9 * 3600.0


def hall_ambient(t: np.ndarray, rng: np.random.Generator, mean: float = 20.0,
                 day_amplitude: float = 3.0, drift_per_day: float = 0.8,
                 start_hour: float = 8.0, door_drops: Sequence[DoorDrop] = (),
                 heating_teeth: float = 0.0, teeth_period_s: float = 1800.0) -> np.ndarray:
    """Hall temperature: day/night cycle (warmest at 15:00), a drifting daily mean
    (random walk of ``drift_per_day`` std per day, interpolated smoothly), optional heating
    'teeth' by day (a thermostat sawtooth of amplitude ``heating_teeth``) and door drops."""
    t = np.asarray(t, dtype=float)
    hours = start_hour + t / 3600.0
    day = day_amplitude * np.cos(2 * np.pi * (hours - 15.0) / 24.0)
    n_days = int(np.ceil((t[-1] if len(t) else 0) / DAY_S)) + 2
    knots = np.cumsum(np.concatenate([[0.0], rng.normal(0.0, drift_per_day, n_days)]))
    drift = np.interp(t / DAY_S, np.arange(n_days + 1), knots)
    amb = mean + day + drift
    if heating_teeth > 0:
        daytime = ((hours % 24.0) >= 6.0) & ((hours % 24.0) < 18.0)
        saw = (t % teeth_period_s) / teeth_period_s
        amb = amb + np.where(daytime, heating_teeth * (saw - 0.5), -heating_teeth * 0.5)
    for d in door_drops:
        amb = amb + door_drop_profile(t, d, rng)
    return amb


def door_drop_profile(t: np.ndarray, d: DoorDrop, rng: np.random.Generator) -> np.ndarray:
    """The change of hall temperature caused by one door opening (<= 0 during the drop)."""
    out = np.zeros_like(t, dtype=float)
    rel = t - d.start_s
    falling = (rel >= 0) & (rel < d.fall_s)
    out[falling] = -d.depth * rel[falling] / d.fall_s
    held = (rel >= d.fall_s) & (rel < d.fall_s + d.open_s)
    out[held] = -d.depth
    after = rel >= d.fall_s + d.open_s
    out[after] = -d.depth * np.exp(-(rel[after] - d.fall_s - d.open_s) / d.recovery_s)
    # afterwards the hall fluctuates (people, heating reacting): smoothed AR(1) noise
    fl = (rel >= d.fall_s) & (rel < d.fall_s + d.fluctuation_s)
    if np.any(fl) and d.fluctuation > 0:
        idx = np.flatnonzero(fl)
        dt = np.median(np.diff(t)) if len(t) > 1 else 60.0
        a = np.exp(-dt / 2700.0)
        e = rng.normal(0.0, d.fluctuation * np.sqrt(1 - a * a), len(idx))
        ar = np.empty(len(idx))
        acc = 0.0
        for j, ej in enumerate(e):
            acc = a * acc + ej
            ar[j] = acc
        taper = np.minimum(1.0, (t[idx] - t[idx[0]]) / 1800.0)
        out[idx] += ar * taper
    return out


def random_levels(t: np.ndarray, rng: np.random.Generator, levels: Sequence[float],
                  hold_s: tuple[float, float], p_levels: Sequence[float] | None = None) -> np.ndarray:
    """A piecewise-constant programme: random levels held for uniform random durations."""
    t = np.asarray(t, dtype=float)
    out = np.empty_like(t)
    i = 0
    while i < len(t):
        level = float(rng.choice(levels, p=p_levels))
        hold = rng.uniform(*hold_s)
        j = int(np.searchsorted(t, t[i] + hold, side="left"))
        j = max(j, i + 1)
        out[i:j] = level
        i = j
    return out


def on_off(t: np.ndarray, rng: np.random.Generator, on_s: tuple[float, float],
           off_s: tuple[float, float], start_on: bool = False) -> np.ndarray:
    """Random switching: 1 while on, 0 while off, with uniform random durations."""
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    i, state = 0, start_on
    while i < len(t):
        dur = rng.uniform(*(on_s if state else off_s))
        j = max(int(np.searchsorted(t, t[i] + dur, side="left")), i + 1)
        out[i:j] = 1.0 if state else 0.0
        i, state = j, not state
    return out


def step_programme(t: np.ndarray, changes: Sequence[tuple[float, float]]) -> np.ndarray:
    """Values from a list of (start time s, value); before the first start: the first value."""
    t = np.asarray(t, dtype=float)
    starts = np.array([c[0] for c in changes], dtype=float)
    vals = np.array([c[1] for c in changes], dtype=float)
    idx = np.searchsorted(starts, t, side="right") - 1
    return vals[np.clip(idx, 0, len(vals) - 1)]


def first_order(t: np.ndarray, target: np.ndarray, tau_s: float, start: float | None = None) -> np.ndarray:
    """A first-order lag (exact for a target held over each step) of ``target``."""
    out = np.empty_like(target, dtype=float)
    y = float(target[0] if start is None else start)
    for k in range(len(t)):
        out[k] = y
        if k + 1 < len(t):
            a = np.exp(-(t[k + 1] - t[k]) / tau_s)
            y = a * y + (1 - a) * target[k]
    return out


def de_bruijn_pairs(n_levels: int) -> list[int]:
    """A sequence over ``n_levels`` symbols in which every ordered pair of successive
    symbols (including repeats) occurs once: the 'optimised' pattern of load case C."""
    a = [0] * (n_levels * 2)
    seq: list[int] = []

    def db(t_: int, p: int) -> None:
        if t_ > 2:
            if 2 % p == 0:
                seq.extend(a[1:p + 1])
        else:
            a[t_] = a[t_ - p]
            db(t_ + 1, p)
            for j in range(a[t_ - p] + 1, n_levels):
                a[t_] = j
                db(t_ + 1, t_)

    db(1, 1)
    return seq + seq[:1]
