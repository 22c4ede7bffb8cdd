"""Re-choosing a twin init's structure once the day after its recording has been probed.

On one day the number of hidden bodies is chosen without seeing how each candidate extrapolates;
the probes a running cell records the next day show exactly that, and no candidate was fitted on
them (each was fitted on the first recording only, so they stay an honest score: refitted on both
days the candidates would be judged on data they saw). Each candidate's twin is run open loop
over the longer recording driven by its recorded inputs and temperatures, and scored at the new
probes by the noise-normalised sum of squared errors (the measure of ``learn``'s adoption test);
the best-scoring one may then replace the structure in use, under the caller's adoption test. No
rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording

from thermal_twin.diagnose.twin_eval import node_states, outputs_from_states
from thermal_twin.machine.schema import load_machine
from thermal_twin.physics.boundary_follow import follow_series, lowered
from thermal_twin.physics.sensor_model import drift_offsets
from thermal_twin.sim.inputs_timeline import timeline_from_recording


@dataclass
class Ranked:
    hidden: int
    cost: float                          # noise-normalised SSE on the new probes
    predicted: dict[str, np.ndarray]     # channel -> open loop at each probe


def open_loop(spec: dict, rec: Recording) -> dict[str, np.ndarray]:
    """The twin's noise-free displacement outputs on every row of ``rec``, driven by its inputs
    (a sensor-fed boundary read from its sensor), from the twin's own initial state."""
    m = load_machine(spec)
    vals = timeline_from_recording(m, rec).resolved(m)
    vals.update(follow_series(m, rec.time_s, vals))
    low = lowered(m)
    net, t, X, tb = node_states(low, rec.time_s, vals)
    out = outputs_from_states(low, net, t, X, tb)
    for c, d in drift_offsets(m, t).items():
        out[c] = out[c] + d
    return out


def probe_cost(values: dict[str, np.ndarray], noise: dict[str, float], predicted: dict[str, np.ndarray]) -> float:
    """sum over channels of (RMSE over the channel's probes / its probe noise)^2; inf without probes."""
    cost, seen = 0.0, False
    for c, v in values.items():
        ok = np.isfinite(v) & np.isfinite(predicted[c])
        if not ok.any():
            continue
        cost += (rmse(v[ok], predicted[c][ok]) / noise[c]) ** 2
        seen = True
    return cost if seen else math.inf


def rank_on_probes(specs: dict[int, dict], rec: Recording, probe_rows: np.ndarray,
                   values: dict[str, np.ndarray], noise: dict[str, float]) -> list[Ranked]:
    """Every candidate (hidden bodies -> fitted twin) run open loop over ``rec`` and scored on the
    probes at rows ``probe_rows`` (values per channel, one per probe), best first."""
    rows = np.asarray(probe_rows, int)
    if rows.size and (rows.min() < 0 or rows.max() >= len(rec)):
        raise ValueError(f"probe_rows: {int(rows.min())}..{int(rows.max())} outside the recording's {len(rec)} rows")
    out = []
    for hidden, spec in specs.items():
        full = open_loop(spec, rec)
        pred = {c: np.asarray(full[c], float)[rows] for c in values}
        out.append(Ranked(hidden, probe_cost(values, noise, pred), pred))
    return sorted(out, key=lambda r: (r.cost, r.hidden))
