"""Probe-and-hold beside a replayed adaptive model (the baseline it must beat): the model's P99 over the whole run
and over its compensation part, and probe-and-hold at the model's Q_prod over the same instants
with the same probe noise and resolution. Used by ``replay``, ``sweep`` and ``bench models``."""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION
from thermal_comp_common import metrics
from thermal_comp_common.components import is_angular
from thermal_comp_common.probe_and_hold import format_beside, probe_and_hold


def _model_p99(result, mask: np.ndarray) -> dict[str, Any]:
    per, p99 = {}, {}
    for c in result.components:
        e = np.asarray(result.true[c], float)
        applied = np.asarray(result.predicted[c], float)
        applied = np.where(np.isfinite(applied), applied, 0.0)   # no prediction = no compensation
        ok = mask & np.isfinite(e)
        v = metrics.p99(e[ok], applied[ok]) if ok.any() else math.nan
        per[c] = {"p99": v}
        if math.isfinite(v):
            p99[c] = v
    comps = result.components
    return {"components": per, "p99_lin_um": metrics.p99_group(p99, [c for c in comps if not is_angular(c)]),
            "p99_ang_um_per_m": metrics.p99_group(p99, [c for c in comps if is_angular(c)])}


def beside_probe_and_hold(result, q_prod_pct: float, noise: Mapping[str, float], resolution_um: float,
                          probe_duration_s: float = metrics.PROBE_CYCLE_DURATION_S, seed: int = 0
                          ) -> tuple[dict[str, Any], str]:
    """(JSON-ready figures, printable text) for a ``VirtualExperimentResult``."""
    comp = np.asarray(result.phase) != PHASE_CALIBRATION
    out: dict[str, Any] = {}
    lines = []
    for name, mask in (("whole_run", np.ones(comp.size, bool)), ("compensation_part", comp)):
        out[name] = beside_in_window(result, mask, q_prod_pct, noise, resolution_um, probe_duration_s, seed)
        if out[name] is not None:
            lines.append(f"{name.replace('_', ' ')}:")
            lines.append(format_beside(out[name]["model"], out[name]["probe_and_hold"], result.components,
                                       label="model"))
    return out, "\n".join(lines)


def beside_in_window(result, mask: np.ndarray, q_prod_pct: float, noise: Mapping[str, float],
                     resolution_um: float, probe_duration_s: float = metrics.PROBE_CYCLE_DURATION_S,
                     seed: int = 0) -> dict[str, Any] | None:
    """The model's P99 on the rows of ``mask`` beside probe-and-hold at ``q_prod_pct`` probing
    within the same rows (None: no row, or no Q_prod to probe at)."""
    if not mask.any() or not (math.isfinite(q_prod_pct) and 0 <= q_prod_pct < 100):
        return None
    t = np.asarray(result.time_s, float)
    true = {c: np.asarray(result.true[c], float) for c in result.components}
    model = _model_p99(result, mask)
    base = probe_and_hold(t, true, q_prod_pct, noise, resolution_um, window=mask,
                          probe_duration_s=probe_duration_s, seed=seed)
    ratio = model["p99_lin_um"] / base["p99_lin_um"] if base["p99_lin_um"] else math.nan
    return {"model": model, "probe_and_hold": base, "p99_lin_ratio": ratio}
