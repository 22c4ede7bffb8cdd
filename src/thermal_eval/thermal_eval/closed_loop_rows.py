"""The project's adaptive models (AGP, TALC) as adaptive rows of ``thermal-comp evaluate``.

Unlike the open-loop models wrapped by :mod:`thermal_eval.adaptive_eval`, these run their own
logic through :class:`talc_model.closed_loop.ClosedLoop` (the virtual experiment): their own
calibration phase from row 0, then the AGP's control measurements and sigma_max-triggered
recalibrations with its uncertainty-weighted hold, or TALC's no-good phases and parameter
updates. A displacement is seen only when the model's own schedule probes. Every probing after
the model leaves its calibration phase counts against the user's budget: :class:`ProbingCap`
refuses a probing that would exceed ``max_probes_per_h`` x the hours since then. Beside each
row: holding the same probes at exactly the same instants. The models are configured from the
recording's columns only (components = displacement column names, sensors = temperature
column names); nothing knows a dataset. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION, AdaptiveModel, ModelStatusData, make_model
from talc_model.sensor_selection import sensor_groups, sensor_medoids
from thermal_comp_common.metrics import q_prod
from thermal_comp_common.recording_csv import Recording
from thermal_eval.adaptive_eval import ProbingBudget
from thermal_eval.evaluation_spec import EvaluationData


class ProbingCap:
    """An AdaptiveModel whose probings after calibration stay within ``max_probes_per_h`` x the
    hours since the model left its calibration phase (a refused probing is asked again later)."""

    def __init__(self, model: AdaptiveModel, max_probes_per_h: float):
        self.model, self.max_probes_per_h = model, float(max_probes_per_h)
        self.kind = model.kind
        self.component_names = list(model.component_names)
        self.calibration_end_s: float | None = None
        self.after_calibration = 0
        self.refused = 0                    # steps at which a probing the model asked for was refused

    @property
    def recalibration_times(self) -> list[float]:
        return list(getattr(self.model, "recalibration_times", []))

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float], machine_state: Mapping[str, float]) -> None:
        self.model.update_inputs(t_s, temperatures, machine_state)

    def predict(self, t_s: float):
        return self.model.predict(t_s)

    def _calibrating(self, t_s: float) -> bool:
        if self.calibration_end_s is None and self.model.status(t_s).phase != PHASE_CALIBRATION:
            self.calibration_end_s = t_s
        return self.calibration_end_s is None

    def probe_due(self, t_s: float) -> bool:
        own = self.model.probe_due(t_s)
        if not own or self._calibrating(t_s):
            return own
        allowed = self.max_probes_per_h * (t_s - self.calibration_end_s) / 3600.0
        if self.after_calibration + 1 > allowed:
            self.refused += 1
            return False
        return True

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        if not self._calibrating(t_s):
            self.after_calibration += 1
        self.model.add_measurement(t_s, measured, applied_compensation)

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        if not self._calibrating(t_s):
            self.after_calibration += 1
        self.model.add_failed_measurement(t_s, reason)

    def status(self, t_s: float) -> ModelStatusData:
        return self.model.status(t_s)


def as_recording(data: EvaluationData) -> tuple[Recording, Any]:
    """The evaluation data as a replay recording and its columns (names kept as they are)."""
    from thermal_eval.virtual_experiment import ReplayColumns
    cols = {f"{s}__temperature": data.temperatures[:, j] for j, s in enumerate(data.sensors)}
    cols.update({ch: data.displacement_um[ch] for ch in data.channels})
    inputs = {}
    if data.inputs is not None:
        for j, name in enumerate(data.input_names):
            cols[f"{name}__input"] = data.inputs[:, j]
            inputs[name] = f"{name}__input"
    columns = ReplayColumns(sensors={s: f"{s}__temperature" for s in data.sensors}, inputs=inputs,
                            errors={ch: ch for ch in data.channels})
    return Recording(data.time_s, cols), columns


def _max_expected_error(data: EvaluationData) -> float:
    n = data.split.n_train
    m = max(float(np.nanmax(np.abs(data.displacement_um[c][:n]))) for c in data.channels)
    return 10.0 * math.ceil(max(m, 1e-9) / 10.0)


def agp_config(data: EvaluationData, budget: ProbingBudget) -> dict[str, Any]:
    """The AGP on every temperature (ARD weighs them), a control measurement at the user's
    schedule, sigma_max = 10 % of the largest training displacement rounded up to 10 um."""
    return {"components": list(data.channels), "sensors": list(data.sensors),
            "control_interval_s": budget.probe_every_h * 3600.0, "probe_duration_s": budget.probe_duration_s,
            "max_expected_error_um": _max_expected_error(data)}


def talc_config(data: EvaluationData, budget: ProbingBudget) -> dict[str, Any]:
    """TALC on the medoid sensors of the training rows' temperature groups (16 correlated inputs
    would need a calibration phase of many hours), probing at the user's schedule afterwards."""
    n = data.split.n_train
    k = sensor_groups(data.temperatures[:n]).n_groups
    return {"component_names": list(data.channels), "angular_components": [],
            "input_names": list(sensor_medoids(data.temperatures[:n], k, data.sensors)),
            "post_cp_interval_h": budget.probe_every_h, "probe_duration_s": budget.probe_duration_s}


#: name -> (model kind, configuration from the data and the budget)
CLOSED_LOOP: dict[str, tuple[str, Callable[[EvaluationData, ProbingBudget], dict]]] = {
    "agp_closed_loop": ("agp", agp_config),
    "talc_closed_loop": ("talc", talc_config),
}


def hold_probes(y: np.ndarray, probe_rows: list[int], n: int) -> np.ndarray:
    """The last probed value at every row (NaN before the first probe): the baseline beside it."""
    out = np.full(n, np.nan)
    bounds = probe_rows[1:] + [n]
    for r, hi in zip(probe_rows, bounds):
        out[r + 1:hi] = y[r]
    return out


@dataclass
class Replay:
    """What one replay gives: compensation per channel (0 where the model gave none), the probe
    rows, and the virtual experiment's result (phases, final status)."""

    compensation: dict[str, np.ndarray]
    probe_rows: list[int]
    result: Any


def replay(data: EvaluationData, model: Any, show_progress: bool = False) -> Replay:
    """The one replay loop of every adaptive model with its own logic (the rows here and the
    replayed rows of ``bench fl-thermal``): every row through ``model``, which sees a displacement
    only when it probes (all channels at once)."""
    from thermal_eval.virtual_experiment import run_virtual_experiment
    rec, columns = as_recording(data)
    res = run_virtual_experiment(rec, model, columns=columns, probed_components=list(data.channels),
                                 progress=show_progress, compute_metrics=False)
    rows = [int(r) for r in np.searchsorted(data.time_s, np.asarray(res.probe_times_s))]
    comp = {ch: np.where(np.isfinite(res.predicted[ch]), res.predicted[ch], 0.0) for ch in data.channels}
    return Replay(comp, rows, res)


def run_closed_loop(data: EvaluationData, name: str, budget: ProbingBudget) -> dict[str, Any]:
    """Replay ``data`` through the model ``name``: compensation per channel, its probe rows, the
    probings after calibration (and how many the cap refused), Q_prod after calibration."""
    kind, config = CLOSED_LOOP[name]
    model = ProbingCap(make_model(kind, config(data, budget)), budget.max_probes_per_h)
    run = replay(data, model)
    res, rows, comp = run.result, run.probe_rows, run.compensation
    end = model.calibration_end_s
    after = [r for r in rows if end is not None and data.time_s[r] >= end]
    hours = (data.time_s[-1] - end) / 3600.0 if end is not None else 0.0
    return {"compensation": comp, "probe_rows": rows, "probe_rows_after_calibration": after,
            "calibration_end_h": None if end is None else round((end - data.time_s[0]) / 3600.0, 2),
            "probings_after_calibration": len(after), "steps_probing_refused_by_budget": model.refused,
            "probings_per_h_after_calibration": round(len(after) / hours, 3) if hours > 0 else math.nan,
            "q_prod_after_calibration_pct": (round(q_prod(len(after), hours * 3600.0, budget.probe_duration_s), 2)
                                             if hours > 0 else math.nan),
            "parameter_updates": int(res.final_status.get("parameter_updates", 0)),
            "no_good_phases": int(res.final_status.get("no_good_phases", 0)),
            "recalibrations": len(res.recalibration_times_s)}
