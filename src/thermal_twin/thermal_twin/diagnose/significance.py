"""Held-out significance of a hypothesis, corrected for the number of hypotheses tried.

A fitted hypothesis adds k parameters to the twin. On the held-out window (never fitted)
its residual sum of squares S1 is compared with S0 of the twin without it by the F
statistic F = ((S0 - S1) / k) / (S1 / (n_eff - k)), where n_eff is the effective number of
independent held-out samples of the augmented twin's residual (n over its integrated
autocorrelation time, :func:`thermal_twin.diagnose.fit.effective_samples`): thermal
residuals are strongly autocorrelated, and the raw sample count would make any term look
significant. The one-sided p-value is the F distribution's survival function.

Every candidate screened in a round is a hypothesis tried, so the round's p-values are
corrected by Holm's step-down procedure over that number (family-wise error ALPHA per
round); a round adopts at most one effect, and the search stops at the first round in
which nothing survives.
"""
from __future__ import annotations

import numpy as np
import scipy.stats

ALPHA = 0.05
PROCEDURE = (f"Holm-Bonferroni step-down over every candidate screened in a round, family-wise "
             f"level {ALPHA:g} per round, on one-sided held-out F tests (k fitted parameters, "
             f"n_eff = held-out samples / integrated autocorrelation time of the residual)")


def holdout_p_value(sse_before: float, sse_after: float, k: int, n_eff: float) -> float:
    """One-sided p-value of the held-out F test (1.0 when the fit got no better)."""
    k = max(int(k), 1)
    dof = max(n_eff - k, 1.0)
    if not (sse_after < sse_before) or sse_before <= 0:
        return 1.0
    f = ((sse_before - sse_after) / k) / (max(sse_after, 1e-300) / dof)
    return float(scipy.stats.f.sf(f, k, dof))


def holm_reject(p_values: list[float], n_tried: int, alpha: float = ALPHA) -> list[bool]:
    """Holm's step-down over ``n_tried`` hypotheses (>= the p-values given; the untested
    ones count as p = 1): True where the null (no improvement) is rejected."""
    m = max(int(n_tried), len(p_values), 1)
    order = np.argsort(p_values, kind="stable")
    reject = [False] * len(p_values)
    for rank, i in enumerate(order):
        if p_values[i] > alpha / (m - rank):
            break
        reject[i] = True
    return reject
