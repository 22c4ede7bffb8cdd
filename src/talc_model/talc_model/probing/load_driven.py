"""Load-driven probing around any adaptive model: dense probings after each machine-load change.

Between scheduled probings a model runs blind, and it is least sure right after a load change
(a spindle-speed step: heat sources jump, the structure starts a new transient that the
calibration may have seen only once). The CNC knows the commanded load, so a probing schedule
may react to it. :class:`LoadDrivenProbing` wraps an :class:`~talc_model.adaptive_model.AdaptiveModel`
and adds, after every change of the machine-state input ``load_key`` (default
``spindle_rpm``), ``measurements`` probings every ``interval_s`` (counted from the end of the
previous probing cycle, like TALC's no-good phase) on top of the model's own schedule. A change
during such a phase is ignored (as TALC ignores a new exceedance in a no-good phase). What the
wrapped model does with the extra measurements is its own logic (the AGP takes an unscheduled
measurement as a control measurement). Probings are counted by the wrapped model (Q_prod).

No rclpy here.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from talc_model.adaptive_model import AdaptiveModel, ModelStatusData, model_from_state


class LoadDrivenProbing:
    """An AdaptiveModel that probes densely after load changes, else as the wrapped model asks."""

    def __init__(self, model: AdaptiveModel, *, load_key: str = "spindle_rpm", interval_s: float = 600.0,
                 measurements: int = 12, probe_duration_s: float = 95.0, min_change: float = 0.0):
        for name, v in (("interval_s", interval_s), ("probe_duration_s", probe_duration_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"LoadDrivenProbing '{name}': {v!r} must be a finite number > 0")
        if not isinstance(measurements, int) or isinstance(measurements, bool) or measurements < 1:
            raise ValueError(f"LoadDrivenProbing 'measurements': {measurements!r} must be an integer >= 1")
        if not (isinstance(min_change, (int, float)) and math.isfinite(min_change) and min_change >= 0):
            raise ValueError(f"LoadDrivenProbing 'min_change': {min_change!r} must be a finite number >= 0")
        self.model = model
        self.kind = f"{model.kind}+load_probing"
        self.component_names = list(model.component_names)
        self.load_key = str(load_key)
        self.interval_s = float(interval_s)
        self.measurements = int(measurements)
        self.probe_duration_s = float(probe_duration_s)
        self.min_change = float(min_change)
        self.last_load: float | None = None
        self.left = 0                       # probings left in the current load phase
        self.due_s = math.inf
        self.load_phases = 0

    @property
    def recalibration_times(self) -> list[float]:
        return list(getattr(self.model, "recalibration_times", []))

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float], machine_state: Mapping[str, float]) -> None:
        self.model.update_inputs(t_s, temperatures, machine_state)
        load = machine_state.get(self.load_key, math.nan)
        if load is None or not math.isfinite(float(load)):
            return                           # unknown load: no decision, keep the last one
        load = float(load)
        if self.last_load is not None and abs(load - self.last_load) > self.min_change and self.left == 0:
            self.left = self.measurements
            self.load_phases += 1
            self.due_s = t_s + self.interval_s
        self.last_load = load

    def predict(self, t_s: float):
        return self.model.predict(t_s)

    def probe_due(self, t_s: float) -> bool:
        own = self.model.probe_due(t_s)          # always asked: it sets the model's reason
        return own or (self.left > 0 and t_s + 1e-9 >= self.due_s)

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None:
        self._count(t_s)
        self.model.add_measurement(t_s, measured, applied_compensation)

    def add_failed_measurement(self, t_s: float, reason: str) -> None:
        self._count(t_s)
        self.model.add_failed_measurement(t_s, reason)

    def _count(self, t_s: float) -> None:
        if self.left > 0 and t_s + 1e-9 >= self.due_s:
            self.left -= 1
        if self.left > 0:
            self.due_s = t_s + self.probe_duration_s + self.interval_s

    def status(self, t_s: float) -> ModelStatusData:
        st = self.model.status(t_s)
        if self.left > 0:
            st.next_probing_due_s = min(st.next_probing_due_s, self.due_s)
        return st

    def to_state(self) -> dict[str, Any]:
        return {"kind": self.kind, "model": self.model.to_state(), "load_key": self.load_key,
                "interval_s": self.interval_s, "measurements": self.measurements,
                "probe_duration_s": self.probe_duration_s, "min_change": self.min_change,
                "last_load": self.last_load, "left": self.left,
                "due_s": None if math.isinf(self.due_s) else self.due_s, "load_phases": self.load_phases}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> "LoadDrivenProbing":
        try:
            w = cls(model_from_state(state["model"]), load_key=state["load_key"], interval_s=state["interval_s"],
                    measurements=int(state["measurements"]), probe_duration_s=state["probe_duration_s"],
                    min_change=state["min_change"])
            w.last_load = state["last_load"]
            w.left = int(state["left"])
            w.due_s = math.inf if state["due_s"] is None else float(state["due_s"])
            w.load_phases = int(state["load_phases"])
        except KeyError as exc:
            raise ValueError(f"LoadDrivenProbing state: missing key {exc}") from None
        return w
