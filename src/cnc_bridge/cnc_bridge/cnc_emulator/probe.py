"""The emulator's optional probing interface: ``ProbeMove`` requests and a twin-backed answer.

``ProbeMove(artefact: UInt32, c_axis_deg: Double, b_axis_deg: Double, start_mm: Double[3],
direction: Double[3], max_travel_mm: Double) -> (triggered: Boolean, position_mm: Double[3])``
on object ``ns=2;s=Probe`` runs one G31-like skip move (arguments as
thermal_comp_msgs/TouchProbe.srv; artefact 0 = sphere, 1 = guide bush). The answer comes
from a Python callable ``probe_move(ProbeRequest) -> (bool, position_mm[3])``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np


@dataclass(frozen=True)
class ProbeRequest:
    """One probing move asked for through ``ProbeMove``."""

    artefact: int
    c_axis_deg: float
    b_axis_deg: float
    start_mm: np.ndarray
    direction: np.ndarray
    max_travel_mm: float
    applied_offsets_um: Mapping[str, float]   # compensation the CNC applies at this moment


ProbeMove = Callable[[ProbeRequest], "tuple[bool, Sequence[float]]"]


def artefact_probe(true_errors: Callable[[], Mapping[str, float]], geometry=None,
                   rng: np.random.Generator | None = None) -> ProbeMove:
    """A ``probe_move`` backed by the twin's artefact geometry.

    ``true_errors()`` returns the current true thermal errors (the twin's ground truth in
    the demo; constants from the command line otherwise).
    """
    # the twin's geometry is loaded only by an emulator that answers probes
    from thermal_twin.machine.artefact_geometry import touch_trigger_position

    def probe(req: ProbeRequest):
        return touch_trigger_position(req.artefact, req.c_axis_deg, req.b_axis_deg,
                                      req.start_mm, req.direction, req.max_travel_mm,
                                      true_errors(), req.applied_offsets_um, geometry, rng)
    return probe
