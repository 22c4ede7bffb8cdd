"""The compensation a probe sees as applied, as the bridge reports it (the node's sink).

Modes (node parameter ``applied_compensation``): ``offsets`` uses what the CNC really holds,
read back by the bridge: with the bridge in kinematic mode the offsets are the components
themselves; X/Y/Z axis offsets are seen by a probing cycle as a translation of the table
frame only (``thermal_comp_common.kinematics.applied_offsets_in_component_space``), so adding
back the whole prediction would count never-applied angular compensation as learned
error. With no offsets yet, or compensation disabled at the CNC, nothing is applied.
``predicted`` assumes the last prediction was applied in full; ``none`` applies nothing.
"""
from __future__ import annotations

import math
from typing import Callable, Mapping

from thermal_comp_common.kinematics import applied_offsets_in_component_space

MODES = ("offsets", "predicted", "none")


class BridgeCompensation:
    """A :class:`talc_model.loop.closed_loop.CompensationSink` fed by the bridge's read-back."""

    def __init__(self, components, mode: str = "offsets",
                 publish: Callable[[float, Mapping[str, float], Mapping[str, float]], None] | None = None):
        if mode not in MODES:
            raise ValueError(f"applied_compensation: {mode!r} is not one of {list(MODES)}")
        self.components = list(components)
        self.mode = mode
        self.publish = publish
        self.last_predicted: dict[str, float] = {}
        self.offsets_seen = False
        self.compensation_enabled = False
        self.offsets: dict[str, float] = {}
        self.stamp_s = -math.inf
        self.b_pos = 0.0

    def on_offsets(self, stamp_s: float, enabled: bool, offsets: Mapping[str, float] | None) -> None:
        """The bridge reported ``offsets`` (None: malformed message, keep the last ones)."""
        self.offsets_seen = True
        self.stamp_s = max(self.stamp_s, stamp_s)
        self.compensation_enabled = bool(enabled)
        if offsets is not None:
            self.offsets = {a: float(v) for a, v in offsets.items() if math.isfinite(v)}

    def must_wait_for(self, t_s: float) -> bool:
        """True when a probe at ``t_s`` should first see the bridge apply t's prediction."""
        return self.mode == "offsets" and self.offsets_seen and self.stamp_s < t_s

    def apply(self, t_s: float, values: Mapping[str, float], stds: Mapping[str, float]) -> None:
        self.last_predicted = dict(values)
        if self.publish is not None:
            self.publish(t_s, values, stds)

    def applied(self, t_s: float) -> dict[str, float]:
        names = self.components
        if self.mode == "none" or (self.mode == "offsets" and not (self.offsets_seen and self.compensation_enabled)):
            return {c: 0.0 for c in names}
        if self.mode == "offsets" and self.offsets:
            if any(c in self.offsets for c in names):
                return {c: self.offsets.get(c, 0.0) for c in names}
            if any(a in self.offsets for a in ("X", "Y", "Z")):
                comp = applied_offsets_in_component_space(self.offsets, self.b_pos)
                return {c: comp.get(c, 0.0) for c in names}
        return {c: (v if math.isfinite(v) else 0.0) for c, v in self.last_predicted.items()}
