"""Probe-driven state update of a calibrated open-loop model: sparse probes, no-good phases, Q_prod.

After its calibration phase a model predicts the thermal error open loop and probes now and
then; between probes the slow part of its error is carried by a :class:`SlowErrorFilter`
(:mod:`talc_model.loop.slow_error_filter`). :func:`run_probe_updates` replays a recording on TALC's
schedule (Blaser thesis §6.2): one probing every ``probe_interval_s`` counted from the end of
the previous cycle, a no-good phase of ``ng_measurements`` probes every ``ng_interval_s``
after a residual beyond the action-control limit. A recording cannot pause, so probing time
is charged in Q_prod (Eq. 6.1) instead of being inserted into the time line.
Background and figures: docs/fl_thermal.md. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np
from thermal_comp_common.metrics import q_prod

from talc_model.loop.slow_error_filter import SlowErrorError, SlowErrorFilter


class ProbeUpdateError(SlowErrorError):
    """Bad input to the probe update; the message names the argument and value."""


@dataclass(frozen=True)
class ProbeSchedule:
    """When to probe (one probing measures every channel)."""

    probe_interval_s: float = 7200.0      # one probing every 2 h after calibration (FL_THERMAL protocol)
    probe_duration_s: float = 95.0        # charged in Q_prod
    acl_um: float = 5.0                   # action-control limit (thesis: 5 um, 5-axis machine)
    ng_interval_s: float = 600.0          # no-good phase: one probing every 10 min ...
    ng_measurements: int = 12             # ... 12 times (thesis Table 6.4)
    interval_from_cycle_end: bool = True

    def __post_init__(self) -> None:
        for name in ("probe_interval_s", "probe_duration_s", "ng_interval_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ProbeUpdateError(f"{name}: {v!r} must be a finite number > 0")
        if not (isinstance(self.acl_um, (int, float)) and not math.isnan(self.acl_um) and self.acl_um > 0):
            raise ProbeUpdateError(f"acl_um: {self.acl_um!r} must be a number > 0 (inf = never a no-good phase)")
        if not isinstance(self.ng_measurements, int) or isinstance(self.ng_measurements, bool) \
                or self.ng_measurements < 1:
            raise ProbeUpdateError(f"ng_measurements: {self.ng_measurements!r} must be an integer >= 1")

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class ProbeUpdateResult:
    compensation: np.ndarray              # N x m: open-loop prediction + estimated slow error (NaN before start)
    bias: np.ndarray                      # N x m: the estimated slow error
    probe_rows: list[int] = field(default_factory=list)
    no_good_phases: int = 0
    load_change_phases: int = 0
    refused_steps: int = 0                # rows at which a due probing was refused by the cap

    def probes_in(self, lo: int, hi: int) -> int:
        return int(sum(lo <= r < hi for r in self.probe_rows))


def run_probe_updates(time_s: np.ndarray, true_um: np.ndarray, prediction_um: np.ndarray, start: int,
                      schedule: ProbeSchedule, filters: Sequence[SlowErrorFilter], stop: int | None = None,
                      last_calibration_probe_s: float | None = None,
                      load_change_rows: Sequence[int] = (),
                      max_probes_per_h: float = math.inf) -> ProbeUpdateResult:
    """Replay rows [start, stop): compensate with ``prediction + b``, probe on the schedule.

    ``true_um`` and ``prediction_um`` are N x m (m channels, one filter each; 1-D = one channel).
    ``true_um`` is read only at probe rows (what the probe sees); ``prediction_um`` is the
    calibrated model's open-loop prediction (causal: row k from inputs <= k only). One probing
    measures every channel; a no-good phase starts when any channel's residual exceeds the ACL.
    The first probing is due one interval after ``last_calibration_probe_s`` (default: the row
    before ``start``), when the model's state was last set from a measurement, so b starts at 0
    with variance 0.

    ``load_change_rows`` (the load-driven variant; empty = the plain schedule): rows where the
    machine's load changes (spindle-speed steps, known to the CNC). A load change is when the
    model is least sure, so it starts a no-good phase as an ACL exceedance would (unless one is
    running): ``ng_measurements`` probings every ``ng_interval_s``, the first one interval after
    the change. Counted in ``load_change_phases``.

    ``max_probes_per_h`` (the user's budget): a due probing is refused (and asked again at the
    next row) while it would make the probings more than that many per hour since row start-1.
    """
    t = np.asarray(time_s, dtype=float)
    y = np.asarray(true_um, dtype=float)
    p = np.asarray(prediction_um, dtype=float)
    y = y[:, None] if y.ndim == 1 else y
    p = p[:, None] if p.ndim == 1 else p
    n = t.size
    if y.shape != p.shape or y.shape[0] != n or y.ndim != 2:
        raise ProbeUpdateError(f"true_um {y.shape} / prediction_um {p.shape} must both have {n} rows")
    m = y.shape[1]
    if len(filters) != m:
        raise ProbeUpdateError(f"filters: {len(filters)} given for {m} channels")
    stop = n if stop is None else int(stop)
    if not 1 <= start < stop <= n:
        raise ProbeUpdateError(f"start/stop: {start}..{stop} is not a range of 1..{n} rows")
    bad = np.argwhere(~np.isfinite(p[start:stop]))
    if bad.size:
        r, c = int(bad[0][0]) + start, int(bad[0][1])
        raise ProbeUpdateError(f"prediction_um: row {r}, channel {c} is {p[r, c]!r}; "
                               "the calibrated model must predict every row after calibration")
    tau = np.array([f.bias_time_constant_s for f in filters])
    ratio = np.array([f.noise_ratio for f in filters])
    comp = np.full((n, m), np.nan)
    bias = np.full((n, m), np.nan)
    b = np.zeros(m)
    var = np.zeros(m)
    t_last = t[start - 1] if last_calibration_probe_s is None else float(last_calibration_probe_s)
    extra = schedule.probe_duration_s if schedule.interval_from_cycle_end else 0.0
    due = t_last + schedule.probe_interval_s + extra
    ng_left = 0
    changes = {int(r) for r in load_change_rows}
    result = ProbeUpdateResult(comp, bias)
    dt = np.diff(t[start - 1:stop])
    decay = np.exp(-dt[:, None] / tau[None, :])
    for i, k in enumerate(range(start, stop)):
        a = decay[i]
        b *= a
        var = var * a * a + (1.0 - a * a)
        comp[k] = p[k] + b
        bias[k] = b
        if k in changes and ng_left == 0:
            ng_left = schedule.ng_measurements
            result.load_change_phases += 1
            due = min(due, t[k] + schedule.ng_interval_s)
        if t[k] + 1e-9 < due:
            continue
        if len(result.probe_rows) + 1 > max_probes_per_h * (t[k] - t[start - 1]) / 3600.0:
            result.refused_steps += 1
            continue
        if not np.all(np.isfinite(y[k])):
            raise ProbeUpdateError(f"true_um: row {k} is {y[k].tolist()!r} at a probing instant")
        result.probe_rows.append(k)
        left_on_part = y[k] - comp[k]
        denom = var + ratio
        gain = np.where(denom > 0, var / np.where(denom > 0, denom, 1.0), 1.0)
        b = b + gain * (y[k] - p[k] - b)
        var = var * (1.0 - gain)
        if ng_left > 0:
            ng_left -= 1
        elif np.any(np.abs(left_on_part) > schedule.acl_um):
            ng_left = schedule.ng_measurements
            result.no_good_phases += 1
        due = t[k] + (schedule.ng_interval_s if ng_left > 0 else schedule.probe_interval_s) + extra
    return result


def q_prod_pct(n_probings: int, duration_s: float, probe_duration_s: float) -> float:
    """Eq. 6.1 via :func:`thermal_comp_common.metrics.q_prod`: 100 (1 - N t_M / t_total)."""
    if not duration_s > 0:
        raise ProbeUpdateError(f"duration_s: {duration_s!r} must be > 0")
    return q_prod(int(n_probings), float(duration_s), float(probe_duration_s))
