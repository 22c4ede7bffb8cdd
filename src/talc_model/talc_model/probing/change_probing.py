"""The model decides when to probe: TALC's rule of a probing due to its own predicted change.

Between probings TALC runs on its model; the error it leaves grows with the change the model
has to predict (a one-pole model gets a transient's shape wrong), so a probing is worth most
where the model predicts a large change since the last one. :func:`change_probe_due` is the
rule (``TalcConfig.change_probe_threshold``, or one threshold per component derived from the
prior's training programme, talc_model.probing.change_threshold): some component's predicted change since
the last probing beyond ``threshold`` times its probe noise, while Q_prod over the last 24 h (not
before ``budget_start_s``: a prior's check phase is not charged to the budget), this probing
counted, stays at or above a floor (the probing budget). docs/talc.md, "The model decides when to probe" and "The probing
threshold from the prior's own virtual experiment".
No rclpy here.
"""
from __future__ import annotations

import math

import numpy as np
from thermal_comp_common.metrics import q_prod

#: the budget's window: Q_prod over the last day (or since the start)
BUDGET_WINDOW_S = 24 * 3600.0


def change_probe_due(x: np.ndarray, measured: np.ndarray, k_last: int, t_s: float, t0: float, step_s: float,
                     noise: np.ndarray, threshold, probe_duration_s: float, min_q_prod_pct: float,
                     budget_start_s: float | None = None) -> bool:
    """True if a probing at ``t_s`` is due by the rule. ``x``: the model's state per grid sample
    and component (the newest row is now), ``measured``: the grid's measured flags, ``k_last``:
    the grid index of the last probing, ``noise``: each component's probe noise (std),
    ``threshold``: one multiple of it or one per component, ``budget_start_s``: probings before
    it do not count in the budget (default ``t0``)."""
    k_now = x.shape[0] - 1
    if not 0 <= k_last < k_now:
        return False
    first = t0 if budget_start_s is None else max(t0, float(budget_start_s))
    if t_s <= first:
        return False
    start = max(first, t_s - BUDGET_WINDOW_S)
    k0 = int(math.ceil((start - t0) / step_s - 1e-9))
    probings = int(np.count_nonzero(measured[k0: k_now + 1].any(axis=1))) + 1
    if q_prod(probings, t_s - start, probe_duration_s) < min_q_prod_pct:
        return False                     # over the budget: the schedule alone
    change = np.abs(x[k_now] - x[k_last])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = change / noise
    return bool(np.any(np.isfinite(ratio) & (ratio > np.asarray(threshold, float))))
