"""Quality indicators of thermal-error models, exactly as the two theses define them.

Blaser (TALC) thesis §4.2.3 and §6.3.2, with E the reference error and Ê the prediction,
r = E - Ê the residual (the compensated error):

- E_RMS  (4.27) = sqrt(sum r^2 / N)
- E_SMAP (4.28) = 100/N sum |r| / (|E| + |Ê|), samples with E = 0 or Ê = 0 left out;
  the thesis first converts under-estimations into equally distant over-estimations
  (spec §2.7 [GAP]); with ``convert_underestimation=True`` (default) Ê is replaced by
  Ê' = E + sign(E)|r|, so the term becomes |r| / (2|E| + |r|).
- E_PV   (4.29) = [max(r) + |min(r)|] / [max(E) + |min(E)|] * 100 %  (as printed)
- PX     (4.30-4.32): MATLAB ``prctile`` of |r| = numpy percentile, method 'hazen'; P99 main.
- Q_Prod (6.1) = (1 - N t_M / t_total) * 100 %
- P99_lin / P99_ang: per-error P99 averaged over the linear / angular errors (spec §2.7 [GAP]:
  per error, then the arithmetic mean).

AGP (Swiss-lathe) thesis §4.2.7: RMS reduction (4.22-4.24) and P2P reduction (4.25-4.27),
E_P2P = max - min.

All functions take arrays and ignore samples where E or Ê is not finite.
"""
from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np

#: Cycle duration of the sphere probing cycle with two tool changes (thesis §5.4), s.
PROBE_CYCLE_DURATION_S = 95.0
#: The production-quality constraint of the parameter sweep: Q_prod >= 95 % (thesis §6.3).
Q_PROD_MIN_PCT = 95.0


def _pair(e, e_hat) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(e, dtype=float).ravel()
    e_hat = np.asarray(e_hat, dtype=float).ravel()
    if e.shape != e_hat.shape:
        raise ValueError(f"reference has {e.size} samples, prediction has {e_hat.size}")
    ok = np.isfinite(e) & np.isfinite(e_hat)
    if not np.any(ok):
        raise ValueError("no sample where both the reference and the prediction are finite")
    return e[ok], e_hat[ok]


def _finite_residual(e, e_hat) -> np.ndarray:
    r = np.asarray(e, dtype=float) - np.asarray(e_hat, dtype=float)
    return r[np.isfinite(r)]


def rmse(e, e_hat) -> float:
    """Root mean square of E - Ê over the samples where both are finite; NaN if none."""
    r = _finite_residual(e, e_hat)
    return float(np.sqrt(np.mean(r ** 2))) if r.size else float("nan")


def mae(e, e_hat) -> float:
    """Mean absolute E - Ê over the samples where both are finite; NaN if none."""
    r = _finite_residual(e, e_hat)
    return float(np.mean(np.abs(r))) if r.size else float("nan")


def e_rms(e, e_hat) -> float:
    """Root mean square of the residual, Eq. 4.27 (raises when no sample is finite)."""
    e, e_hat = _pair(e, e_hat)
    return rmse(e, e_hat)


def e_smap(e, e_hat, convert_underestimation: bool = True) -> float:
    """Symmetric mean absolute percentage error, Eq. 4.28 (0..100 %)."""
    e, e_hat = _pair(e, e_hat)
    keep = (e != 0) & (e_hat != 0)
    e, e_hat = e[keep], e_hat[keep]
    if e.size == 0:
        return float("nan")
    r = np.abs(e - e_hat)
    if convert_underestimation:
        denom = 2.0 * np.abs(e) + r
    else:
        denom = np.abs(e) + np.abs(e_hat)
    return float(100.0 * np.mean(r / denom))


def e_pv(e, e_hat) -> float:
    """Peak-to-peak ratio, Eq. 4.29 as printed, in %."""
    e, e_hat = _pair(e, e_hat)
    r = e - e_hat
    den = np.max(e) + abs(np.min(e))
    if den == 0:
        return float("nan")
    return float((np.max(r) + abs(np.min(r))) / den * 100.0)


def px(e, e_hat, x: float = 99.0) -> float:
    """X-th percentile of |E - Ê|, Eqs 4.30-4.32 (MATLAB prctile = numpy 'hazen')."""
    e, e_hat = _pair(e, e_hat)
    return float(np.percentile(np.abs(e - e_hat), x, method="hazen"))


def p99(e, e_hat) -> float:
    """99th percentile of the absolute residual (the thesis's main indicator)."""
    return px(e, e_hat, 99.0)


def q_prod(n_measurements: int, t_total_s: float,
           t_measurement_s: float = PROBE_CYCLE_DURATION_S) -> float:
    """Productivity, Eq. 6.1, in %: 100 (1 - N t_M / t_total)."""
    if t_total_s <= 0:
        return 100.0 if n_measurements == 0 else float("nan")
    return float(100.0 * (1.0 - n_measurements * t_measurement_s / t_total_s))


def rms_reduction(e, e_hat) -> float:
    """(E_RMS,U - E_RMS,C) / E_RMS,U * 100 %, AGP thesis Eqs 4.22-4.24."""
    e, e_hat = _pair(e, e_hat)
    u = float(np.sqrt(np.mean(e ** 2)))
    c = float(np.sqrt(np.mean((e - e_hat) ** 2)))
    return float("nan") if u == 0 else 100.0 * (u - c) / u


def p2p_reduction(e, e_hat) -> float:
    """(E_P2P,U - E_P2P,C) / E_P2P,U * 100 %, AGP thesis Eqs 4.25-4.27."""
    e, e_hat = _pair(e, e_hat)
    u = float(np.max(e) - np.min(e))
    r = e - e_hat
    c = float(np.max(r) - np.min(r))
    return float("nan") if u == 0 else 100.0 * (u - c) / u


def indicators(e, e_hat) -> dict[str, float]:
    """All per-error indicators of the TALC thesis for one error component."""
    return {"rms": e_rms(e, e_hat), "smap_pct": e_smap(e, e_hat), "pv_pct": e_pv(e, e_hat),
            "p99": p99(e, e_hat), "p99_uncompensated": p99(e, np.zeros_like(np.asarray(e, float))),
            "rms_reduction_pct": rms_reduction(e, e_hat), "p2p_reduction_pct": p2p_reduction(e, e_hat)}


def p99_group(per_error_p99: Mapping[str, float], names: Iterable[str]) -> float:
    """Arithmetic mean of the per-error P99 of ``names`` (P99_lin / P99_ang, §6.3.3)."""
    vals = [per_error_p99[n] for n in names if n in per_error_p99 and np.isfinite(per_error_p99[n])]
    return float(np.mean(vals)) if vals else float("nan")
