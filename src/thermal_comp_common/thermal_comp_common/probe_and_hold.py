"""Probe-and-hold: the baseline every adaptive model must beat.

No model at all: probe evenly, at the interval that gives the same productivity Q_prod as the
model (Eq. 6.1: interval = t_M / (1 - Q_prod)), with the same probe noise and resolution, and
hold each measured total error as the compensation until the next probe. Scored over the same
evaluation window with the same P99 (``thermal_comp_common.metrics``). A model earns its place
only by beating this at equal Q_prod. No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from thermal_comp_common import metrics
from thermal_comp_common.components import is_angular

#: Probe noise (k = 1) and resolution of the sphere cycle, Blaser thesis Table 5.4: the demo's
#: baseline uses them (thermal_eval's replay has the same values as its defaults).
TABLE_5_4_NOISE_LINEAR_UM = 0.25
TABLE_5_4_NOISE_ANGULAR_UM_PER_M = 1.2
TABLE_5_4_RESOLUTION_UM = 0.25


def table_5_4_noise(components: Sequence[str]) -> dict[str, float]:
    """Probe noise std per component after Table 5.4 (um/m for the angular ones)."""
    return {c: TABLE_5_4_NOISE_ANGULAR_UM_PER_M if is_angular(c) else TABLE_5_4_NOISE_LINEAR_UM
            for c in components}


def probe_interval_s(q_prod_pct: float, probe_duration_s: float) -> float:
    """Even probing interval (start to start) that costs ``100 - q_prod_pct`` % of the time."""
    if not (math.isfinite(q_prod_pct) and 0.0 <= q_prod_pct < 100.0):
        raise ValueError(f"probe-and-hold: q_prod_pct {q_prod_pct!r} must be in [0, 100)")
    if not (math.isfinite(probe_duration_s) and probe_duration_s > 0):
        raise ValueError(f"probe-and-hold: probe_duration_s {probe_duration_s!r} must be > 0")
    return probe_duration_s / (1.0 - q_prod_pct / 100.0)


def hold_compensation(time_s: np.ndarray, true: np.ndarray, interval_s: float, noise_std: float,
                      resolution: float, rng: np.random.Generator) -> np.ndarray:
    """Compensation held at each instant: the last probed total error (noisy, quantised) taken
    strictly before that instant (a probe's result applies after the cycle); 0 before the first.
    Probes at t0, t0 + interval, ... land on the first recorded instant at or after each time."""
    t = np.asarray(time_s, float)
    e = np.asarray(true, float)
    times = np.arange(t[0], t[-1] + 1e-9, interval_s)
    rows = np.unique(np.searchsorted(t, times - 1e-9, side="left"))
    rows = rows[rows < t.size]
    meas = e[rows] + (rng.normal(0.0, noise_std, rows.size) if noise_std > 0 else 0.0)
    if resolution > 0:
        meas = np.round(meas / resolution) * resolution
    ok = np.isfinite(meas)
    rows, meas = rows[ok], meas[ok]
    idx = np.searchsorted(rows, np.arange(t.size), side="left") - 1   # last probe strictly before
    comp = np.where(idx >= 0, meas[np.clip(idx, 0, None)] if meas.size else 0.0, 0.0)
    return comp


def probe_and_hold(time_s: np.ndarray, true: Mapping[str, np.ndarray], q_prod_pct: float,
                   probe_noise: Mapping[str, float], resolution_um: float = 0.0,
                   window: np.ndarray | None = None, probe_duration_s: float = 95.0,
                   seed: int = 0) -> dict[str, Any]:
    """P99 of probe-and-hold per component over ``window`` (bool mask, default all instants).

    ``true``: total error per component; ``probe_noise``: std per component (um or um/m).
    Returns ``{"interval_h", "q_prod_pct", "components": {c: {"p99", "unit"}}, "p99_lin_um",
    "p99_ang_um_per_m"}``.
    """
    t = np.asarray(time_s, float)
    if t.size < 2:
        raise ValueError(f"probe-and-hold: time_s has {t.size} instants, need at least 2")
    interval = probe_interval_s(q_prod_pct, probe_duration_s)
    mask = np.ones(t.size, bool) if window is None else np.asarray(window, bool)
    if mask.shape != t.shape:
        raise ValueError(f"probe-and-hold: window has shape {mask.shape}, time_s {t.shape}")
    rng = np.random.default_rng(seed)
    per: dict[str, dict[str, Any]] = {}
    p99: dict[str, float] = {}
    for c in sorted(true):
        if c not in probe_noise:
            raise ValueError(f"probe-and-hold: no probe noise for component {c!r}")
        e = np.asarray(true[c], float)
        comp = hold_compensation(t, e, interval, float(probe_noise[c]), resolution_um, rng)
        ok = mask & np.isfinite(e)
        v = metrics.p99(e[ok], comp[ok]) if ok.any() else math.nan
        per[c] = {"p99": v, "unit": "um/m" if is_angular(c) else "um"}
        if math.isfinite(v):
            p99[c] = v
    comps = list(true)
    return {"interval_h": interval / 3600.0, "q_prod_pct": q_prod_pct, "components": per,
            "p99_lin_um": metrics.p99_group(p99, [c for c in comps if not is_angular(c)]),
            "p99_ang_um_per_m": metrics.p99_group(p99, [c for c in comps if is_angular(c)])}


def format_beside(model: Mapping[str, Any], baseline: Mapping[str, Any], components: Sequence[str],
                  label: str = "model") -> str:
    """Two lines: the model's P99 and probe-and-hold's at the same Q_prod, per component."""
    def cell(v) -> str:
        return f"{v:9.2f}" if v is not None and math.isfinite(v) else "      n/a"
    lines = ["".ljust(26) + "".join(c.rjust(9) for c in components) + "  P99_lin  P99_ang",
             f"{label} P99".ljust(26) + "".join(cell(model["components"][c]["p99"]) for c in components)
             + cell(model["p99_lin_um"]) + cell(model["p99_ang_um_per_m"]),
             f"probe-and-hold P99".ljust(26) + "".join(cell(baseline["components"][c]["p99"]) for c in components)
             + cell(baseline["p99_lin_um"]) + cell(baseline["p99_ang_um_per_m"])]
    ratio = model["p99_lin_um"] / baseline["p99_lin_um"] if baseline["p99_lin_um"] else math.nan
    lines.append(f"probe-and-hold at the same Q_prod {baseline['q_prod_pct']:.2f} % (a probe every "
                 f"{baseline['interval_h']:.2f} h): {label} P99_lin / probe-and-hold = {ratio:.2f}"
                 " (goal: at most 0.5)")
    return "\n".join(lines)
