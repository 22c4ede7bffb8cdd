"""Locating a mismatch: which channels, which time windows, which operating regimes.

Pure numpy. Inputs are the residuals (recording minus twin) per channel, the time vector
and the recording's inputs. Effect sizes are in the channel's unit (degC for sensors,
um or um/m for error channels).

- :func:`operating_regimes`: boolean regime masks from the inputs (spindle running,
  coolant on, door open) and the time of day (day 06-22 h / night).
- :func:`regime_effects`: mean residual inside vs. outside each regime, per channel.
- :func:`locate_windows`: contiguous time windows where the smoothed residual stands out
  (above four times the smoothed noise and above half its peak), merged over channels
  when they overlap,
  each labelled with the regime that dominates it.
"""
from __future__ import annotations

import math

import numpy as np

from thermal_twin.diagnose.statistics import fill_gaps, is_speed_like


def noise_sigma(x: np.ndarray) -> float:
    """Robust white-noise level of a series from its first differences (MAD)."""
    d = np.diff(fill_gaps(x))
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def moving_average(x: np.ndarray, w: int) -> np.ndarray:
    """Centred moving average over w samples; near the ends over the samples that exist
    (no padding, which would weigh the first and last reading w/2 times)."""
    x = fill_gaps(x)
    if w <= 1 or x.size <= w:
        return x.copy()
    k = np.ones(w)
    num = np.convolve(x, k, mode="same")
    den = np.convolve(np.ones_like(x), k, mode="same")
    return num / den


def _input_kind(name: str) -> str | None:
    n = name.lower()
    if is_speed_like(n):
        return "spindle running"
    if "coolant" in n or "mwf" in n or n.startswith("oil") or "_oil" in n:
        return "coolant on"
    if "door" in n:
        return "door open"
    return None


def operating_regimes(time_s: np.ndarray, inputs: dict[str, np.ndarray],
                      start_hour: float = 0.0) -> dict[str, np.ndarray]:
    """Regime masks. Speed-like inputs count as running above 1 % of their maximum;
    on/off inputs (coolant, door) above 0.5. ``start_hour`` is the clock time of
    ``time_s == 0`` (hours), for the day (06-22 h) / night split."""
    t = np.asarray(time_s, dtype=float)
    out: dict[str, np.ndarray] = {}
    for name, u in inputs.items():
        kind = _input_kind(name)
        if kind is None:
            continue
        u = fill_gaps(u)
        if kind == "spindle running":
            thr = 0.01 * float(np.max(np.abs(u))) if np.any(u) else 0.5
            mask = np.abs(u) > thr
        else:
            mask = u > 0.5
        label = kind if kind != "spindle running" or sum(
            1 for n in inputs if _input_kind(n) == kind) == 1 else f"{name} running"
        out[label] = mask
    hour = ((t / 3600.0) + start_hour) % 24.0
    out["day (06-22 h)"] = (hour >= 6.0) & (hour < 22.0)
    return out


def regime_effects(residuals: dict[str, np.ndarray], regimes: dict[str, np.ndarray],
                   units: dict[str, str]) -> list[dict]:
    """Per regime and channel: mean residual inside and outside the regime and their
    difference (the effect size), sorted by |difference| relative to the channel's RMS."""
    rows = []
    for reg, mask in regimes.items():
        if mask.all() or not mask.any():
            continue
        for ch, r in residuals.items():
            r = fill_gaps(r)
            rms = float(np.sqrt(np.mean(r ** 2))) or 1.0
            m_in, m_out = float(np.mean(r[mask])), float(np.mean(r[~mask]))
            rows.append({"regime": reg, "channel": ch, "unit": units.get(ch, ""),
                         "mean_in": m_in, "mean_out": m_out, "effect": m_in - m_out,
                         "share_of_time": float(mask.mean()),
                         "relative": abs(m_in - m_out) / rms})
    rows.sort(key=lambda d: -d["relative"])
    return rows


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of mask."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _regime_label(regimes: dict[str, np.ndarray], a: int, b: int) -> str:
    parts = []
    for reg, mask in regimes.items():
        share = float(mask[a:b].mean())
        if reg.startswith("day"):
            parts.append("day" if share >= 0.5 else "night")
        elif share >= 0.5:
            parts.append(reg)
        else:
            parts.append(reg.replace("running", "stopped").replace(" on", " off")
                         .replace(" open", " closed"))
    return ", ".join(parts)


def locate_windows(time_s: np.ndarray, residuals: dict[str, np.ndarray],
                   regimes: dict[str, np.ndarray], units: dict[str, str],
                   smooth_s: float = 3600.0, max_windows: int = 12) -> list[dict]:
    """Time windows where a channel's smoothed residual exceeds max(4 sigma of the smoothed
    noise, 0.5 * its peak); windows of several channels that overlap by at least half of their
    union are merged. At most ``max_windows`` are kept, the strongest (sum over channels
    of the peak relative to the channel's smoothed-residual RMS). Each window: start_s,
    end_s, channels, regime, and per channel the peak smoothed residual (``effect``) in
    its unit. Sorted by start time."""
    t = np.asarray(time_s, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    w = int(max(1, round(smooth_s / dt)))
    per_ch: list[tuple[int, int, str, float]] = []
    scale: dict[str, float] = {}
    for ch, r in residuals.items():
        s = moving_average(r, w)
        scale[ch] = float(np.sqrt(np.mean(s ** 2))) or 1.0
        peak = float(np.max(np.abs(s)))
        floor = 4.0 * noise_sigma(r) / math.sqrt(w)   # 4 sigma: many windows are looked at
        thr = max(floor, 0.5 * peak, 1e-9)
        if peak <= floor:
            continue
        for a, b in _segments(np.abs(s) > thr):
            if b - a < max(2, w // 4):
                continue
            k = a + int(np.argmax(np.abs(s[a:b])))
            per_ch.append((a, b, ch, float(s[k])))
    if not per_ch:
        return []
    per_ch.sort()
    merged: list[dict] = []
    for a, b, ch, eff in per_ch:
        for m in merged:   # same window if the overlap is at least half of the union
            inter = min(b, m["_b"]) - max(a, m["_a"])
            union = max(b, m["_b"]) - min(a, m["_a"])
            if inter >= 0.5 * union:
                m["_a"], m["_b"] = min(a, m["_a"]), max(b, m["_b"])
                old = m["effects"].get(ch)
                m["effects"][ch] = eff if old is None or abs(eff) > abs(old) else old
                m["score"] += abs(eff) / scale[ch]
                break
        else:
            merged.append({"_a": a, "_b": b, "effects": {ch: eff}, "score": abs(eff) / scale[ch]})
    out = []
    for m in merged:
        a, b = m["_a"], m["_b"]
        out.append({"start_s": float(t[a]), "end_s": float(t[min(b, t.size - 1)]),
                    "channels": sorted(m["effects"]),
                    "regime": _regime_label(regimes, a, b),
                    "effect": {ch: {"value": v, "unit": units.get(ch, "")}
                               for ch, v in sorted(m["effects"].items())}})
    order = np.argsort([-m["score"] for m in merged], kind="stable")
    out = [out[i] for i in order[:max_windows]]
    out.sort(key=lambda d: d["start_s"])
    return out
