"""Evaluation rows: the project's adaptive models (AGP, TALC) scored on a recording by ``thermal-comp evaluate``.

Unlike the open-loop models wrapped by :mod:`thermal_eval.evaluate.adaptive`, these run their own
logic. Two ways to start:

- **from row 0** (``agp_closed_loop``, ``talc_closed_loop``): through
  :class:`talc_model.loop.closed_loop.ClosedLoop` (the virtual experiment), with their own calibration
  phase, then the AGP's control measurements and sigma_max-triggered recalibrations with its
  uncertainty-weighted hold, or TALC's no-good phases and parameter updates;
  :class:`ProbingCap` holds them to the budget;
- **fitted on the training rows** (rows ``talc_calibrated*``, ``agp_calibrated``): the training
  rows are their calibration phase (one charged probing per 5-min grid sample), their settings
  chosen by a walk-forward inside them (:mod:`thermal_eval.evaluate.talc_rows`,
  :mod:`thermal_eval.evaluate.agp_rows`), and they probe after it under the same budget and cap.

A displacement is seen only when the model probes. Every probing after calibration counts
against the user's budget (``max_probes_per_h`` x the hours since the end of calibration),
Q_prod after calibration is counted the same way for every row, and beside each row is holding
the same probes at exactly the same instants. The models are configured from the recording's
columns only (components = displacement column names, sensors = temperature column names,
machine inputs = input columns); nothing knows a dataset. No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION, AdaptiveModel, ModelStatusData, make_model
from talc_model.open_loop.sensor_selection import sensor_groups, sensor_medoids
from thermal_comp_common.metrics import q_prod
from thermal_comp_common.recording_csv import Recording
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.training_fit import refused_by_cap
from thermal_eval.evaluate.spec import EvaluationData
from thermal_eval.evaluate.agp_rows import run_training_fit_agp
from thermal_eval.evaluate.talc_rows import run_training_fit_talc
from thermal_eval.replay.virtual_experiment import ReplayColumns, run_virtual_experiment


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
        if refused_by_cap(self.after_calibration, t_s, self.calibration_end_s, self.max_probes_per_h):
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


def hold_probes(y: np.ndarray, probe_rows: list[int], n: int) -> np.ndarray:
    """The last value probed strictly before each row (NaN up to the first probe; a probe row is
    compensated before its probe, so it holds the one before): the baseline beside each row."""
    out = np.full(n, np.nan)
    bounds = probe_rows[1:] + [n - 1]
    for r, hi in zip(probe_rows, bounds):
        out[r + 1:hi + 1] = y[r]
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
    rec, columns = as_recording(data)
    res = run_virtual_experiment(rec, model, columns=columns, probed_components=list(data.channels),
                                 progress=show_progress, compute_metrics=False)
    rows = [int(r) for r in np.searchsorted(data.time_s, np.asarray(res.probe_times_s))]
    comp = {ch: np.where(np.isfinite(res.predicted[ch]), res.predicted[ch], 0.0) for ch in data.channels}
    return Replay(comp, rows, res)


def _counts(data: EvaluationData, rows: list[int], end_s: float | None, budget: ProbingBudget) -> dict[str, Any]:
    """The probings after the end of calibration, per hour, and Q_prod after calibration."""
    after = [r for r in rows if end_s is not None and data.time_s[r] >= end_s]
    hours = (data.time_s[-1] - end_s) / 3600.0 if end_s is not None else 0.0
    return {"probe_rows": rows, "probe_rows_after_calibration": after,
            "calibration_end_h": None if end_s is None else round((end_s - data.time_s[0]) / 3600.0, 2),
            "probings_after_calibration": len(after),
            "probings_per_h_after_calibration": round(len(after) / hours, 3) if hours > 0 else math.nan,
            "q_prod_after_calibration_pct": (round(q_prod(len(after), hours * 3600.0, budget.probe_duration_s), 2)
                                             if hours > 0 else math.nan)}


def _from_row_0(kind: str, config: Callable[[EvaluationData, ProbingBudget], dict]):
    def run(data: EvaluationData, budget: ProbingBudget) -> dict[str, Any]:
        model = ProbingCap(make_model(kind, config(data, budget)), budget.max_probes_per_h)
        rep = replay(data, model)
        res = rep.result
        return {"compensation": rep.compensation, **_counts(data, rep.probe_rows, model.calibration_end_s, budget),
                "calibration": "own, from row 0", "steps_probing_refused_by_budget": model.refused,
                "parameter_updates": int(res.final_status.get("parameter_updates", 0)),
                "no_good_phases": int(res.final_status.get("no_good_phases", 0)),
                "recalibrations": len(res.recalibration_times_s)}
    return run


def _training_fit_row(data: EvaluationData, budget: ProbingBudget, calibration_rows: list[int], after: list[int],
                      compensation: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """The row of a model fitted on the training rows (its calibration phase): those probings are the
    first probe rows (what the hold beside it starts from), Q_prod over the whole recording
    charges them too."""
    n = data.split.n_train
    rows = list(calibration_rows) + list(after)
    total_s = float(data.time_s[-1] - data.time_s[0])
    return {"compensation": {ch: np.where(np.isfinite(c), c, 0.0) for ch, c in compensation.items()},
            **_counts(data, rows, float(data.time_s[n - 1]), budget),
            "calibration": "the training rows", "calibration_probings": len(calibration_rows),
            "q_prod_pct": round(q_prod(len(rows), total_s, budget.probe_duration_s), 2)}


def _training_fit_talc(with_inputs: bool, load_probing: bool):
    def run(data: EvaluationData, budget: ProbingBudget) -> dict[str, Any]:
        r = run_training_fit_talc(data, budget, with_inputs=with_inputs, load_probing=load_probing, arx_cache={})
        return {**_training_fit_row(data, budget, r.calibration_rows, r.probe_rows, r.compensation),
                "steps_probing_refused_by_budget": r.refused_steps, "parameter_updates": 0,
                "no_good_phases": r.no_good_phases, "load_change_phases": r.load_change_phases,
                "recalibrations": 0, "settings": r.settings}
    return run


def _training_fit_agp(data: EvaluationData, budget: ProbingBudget) -> dict[str, Any]:
    r = run_training_fit_agp(data, budget)
    tr = r.trajectory
    return {**_training_fit_row(data, budget, r.calibration_rows, tr.probe_rows, r.compensation),
            "steps_probing_refused_by_budget": tr.refused_steps, "parameter_updates": tr.refits_optimised,
            "no_good_phases": 0, "recalibrations": tr.sigma_probes, "settings": r.settings()}


#: name -> runner (data, budget) -> the row's arrays and counts (:func:`run_closed_loop`)
CLOSED_LOOP: dict[str, Callable[[EvaluationData, ProbingBudget], dict[str, Any]]] = {
    "agp_closed_loop": _from_row_0("agp", agp_config),
    "talc_closed_loop": _from_row_0("talc", talc_config),
    "talc_calibrated": _training_fit_talc(False, False),
    "talc_calibrated_inputs": _training_fit_talc(True, False),
    "talc_calibrated_load_probing": _training_fit_talc(False, True),
    "talc_calibrated_inputs_load_probing": _training_fit_talc(True, True),
    "agp_calibrated": _training_fit_agp,
}


def run_closed_loop(data: EvaluationData, name: str, budget: ProbingBudget) -> dict[str, Any]:
    """Run the model ``name`` on ``data``: compensation per channel, its probe rows (calibration
    probings included), those after calibration, how many steps the cap refused, Q_prod after
    calibration (and the model's own counts)."""
    return CLOSED_LOOP[name](data, budget)
