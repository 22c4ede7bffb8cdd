"""Plain results of the cell API: what a script gets back instead of ROS messages.

Each one is a frozen dataclass built from the message it came in, with the stamp in seconds
and errors as ``{component: value}``; the message itself stays available as ``msg``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from thermal_comp_msgs.msg import ModelStatus, ThermalErrors

PHASES = {ModelStatus.PHASE_CALIBRATION: "calibration", ModelStatus.PHASE_COMPENSATION: "compensation",
          ModelStatus.PHASE_NO_GOOD: "no_good"}
UNITS = {ThermalErrors.UNIT_UM: "um", ThermalErrors.UNIT_UM_PER_M: "um/m"}


def stamp_s(stamp) -> float:
    """A builtin_interfaces/Time as seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


@dataclass(frozen=True)
class Errors:
    """Thermal errors by component, with their units and standard uncertainties (k=1)."""
    stamp_s: float
    frame_id: str
    model_kind: str
    values: dict[str, float]
    units: dict[str, str]
    uncertainties: dict[str, float]
    msg: Any = field(repr=False, compare=False, default=None)

    @classmethod
    def from_msg(cls, m: ThermalErrors) -> "Errors":
        names = list(m.component_names)
        if not (len(m.values) == len(names) == len(m.units)):
            raise ValueError(f"ThermalErrors: {len(names)} component_names, {len(m.values)} values, "
                             f"{len(m.units)} units (must be equal)")
        unc = list(m.uncertainties) if len(m.uncertainties) == len(names) else [math.nan] * len(names)
        return cls(stamp_s(m.header.stamp), m.header.frame_id, m.model_kind,
                   dict(zip(names, map(float, m.values))),
                   {n: UNITS.get(u, f"unit {u}") for n, u in zip(names, m.units)},
                   dict(zip(names, map(float, unc))), m)


@dataclass(frozen=True)
class ProbeResult:
    """The result of one probing cycle (``success`` False: ``message`` says why)."""
    success: bool
    message: str
    errors: Errors
    duration_s: float
    fit_residual_rms_um: float
    repeatability_check_um: float
    msg: Any = field(repr=False, compare=False, default=None)

    @classmethod
    def from_msg(cls, r) -> "ProbeResult":
        return cls(bool(r.success), r.message, Errors.from_msg(r.errors), float(r.duration_s),
                   float(r.fit_residual_rms_um), float(r.repeatability_check_um), r)


@dataclass(frozen=True)
class Status:
    """The model's state as its latest ModelStatus says it."""
    stamp_s: float
    model_kind: str
    phase: str
    probing_cycles: int
    failed_probing_cycles: int
    parameter_updates: int
    training_samples: int
    q_prod_pct: float
    next_probing_due_s: float
    max_uncertainty: float
    excluded_sensor_ids: list[str]
    message: str
    msg: Any = field(repr=False, compare=False, default=None)

    @classmethod
    def from_msg(cls, m: ModelStatus) -> "Status":
        return cls(stamp_s(m.header.stamp), m.model_kind, PHASES.get(m.phase, f"phase {m.phase}"),
                   int(m.probing_cycles), int(m.failed_probing_cycles), int(m.parameter_updates),
                   int(m.training_samples), float(m.q_prod_pct), stamp_s(m.next_probing_due),
                   float(m.max_uncertainty), list(m.excluded_sensor_ids), m.message, m)
