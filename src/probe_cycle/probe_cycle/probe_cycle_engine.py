"""A probing goal from start to result: plan, execute through a backend, evaluate, keep the zero.

This is the whole behaviour of the ``probe_cycle`` action server, free of ROS:
:class:`ProbeCycleEngine.run` takes a :class:`GoalSpec`, a backend and optional feedback
and cancel callbacks. It returns a :class:`~probe_cycle.cycle_result.CycleResult`, which
either carries measured errors with uncertainties or fails with a message and no errors.
A reference is replaced only by a successful cycle, and it is saved at once when the
engine has a reference file.
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Callable

from thermal_twin.machine.artefact_geometry import (ARTEFACT_GUIDE_BUSH, ARTEFACT_SPHERE,
                                            GUIDE_BUSH_COMPONENT, ArtefactGeometry)

from probe_cycle.cycle_plan import (DEFAULT_C_ANGLES_DEG, DEFAULT_GUIDE_BUSH_REPEATS,
                                    DEFAULT_SPHERE_POINTS, CyclePlan, GuideBushTiming,
                                    PlanError, SphereTiming, plan_guide_bush_cycle,
                                    plan_sphere_cycle)
from probe_cycle.cycle_reference import ReferenceStore
from probe_cycle.cycle_result import CycleLimits, CycleResult, failure
from probe_cycle.cycle_runner import PointCallback, execute_plan
from probe_cycle.guide_bush_cycle import evaluate_guide_bush_cycle
from probe_cycle.probe_backend import ProbeBackend
from probe_cycle.sphere_cycle import evaluate_sphere_cycle
from probe_cycle.sphere_fit import probe_point_sigma_um

GUIDE_BUSH_TOOL_POSITION = GUIDE_BUSH_COMPONENT.split("_")[0]   # "GB"
MAX_POINTS_PER_INDEXING = 64   # a plausible upper end; more only lengthens the cycle


@dataclass(frozen=True)
class GoalSpec:
    """The fields of a ProbeCycle goal (0 / empty = default)."""

    artefact: int = ARTEFACT_SPHERE
    set_reference: bool = False
    points_per_indexing: int = 0
    c_angles_deg: tuple[float, ...] = ()
    timeout_s: float = 0.0
    tool_position: str = ""


class ProbeCycleEngine:
    def __init__(self, geometry: ArtefactGeometry, limits: CycleLimits = CycleLimits(),
                 sphere_timing: SphereTiming = SphereTiming(),
                 guide_bush_timing: GuideBushTiming = GuideBushTiming(),
                 default_timeout_s: float = 300.0,
                 references: ReferenceStore | None = None,
                 reference_path: str | os.PathLike | None = None):
        self.geometry = geometry
        probe = geometry.probe
        gb = geometry.guide_bush
        self.sphere_point_sigma_um = probe_point_sigma_um(probe.sigma_um,
                                                          probe.axis_resolution_um)
        self.guide_bush_point_sigma_um = probe_point_sigma_um(gb.sigma_um, gb.level_spacing_um)
        self.limits = dataclasses.replace(limits, point_sigma_um=self.sphere_point_sigma_um)
        self.sphere_timing = sphere_timing
        self.guide_bush_timing = guide_bush_timing
        self.default_timeout_s = float(default_timeout_s)
        self.reference_path = reference_path
        if references is None:
            references = (ReferenceStore.load(reference_path) if reference_path
                          else ReferenceStore())
        self.references = references

    # ------------------------------------------------------------------ planning
    def plan(self, goal: GoalSpec) -> CyclePlan:
        if not 0 <= goal.points_per_indexing <= MAX_POINTS_PER_INDEXING:
            raise PlanError(f"points_per_indexing: {goal.points_per_indexing} is outside "
                            f"0..{MAX_POINTS_PER_INDEXING} (0 = default)")
        if goal.artefact == ARTEFACT_SPHERE:
            if goal.tool_position:
                raise PlanError(f"tool_position: {goal.tool_position!r} given for the sphere "
                                f"cycle; leave it empty")
            return plan_sphere_cycle(
                self.geometry, tuple(goal.c_angles_deg) or DEFAULT_C_ANGLES_DEG,
                goal.points_per_indexing or DEFAULT_SPHERE_POINTS, self.sphere_timing)
        if goal.artefact == ARTEFACT_GUIDE_BUSH:
            if goal.tool_position not in ("", GUIDE_BUSH_TOOL_POSITION):
                raise PlanError(f"tool_position: {goal.tool_position!r} has no probing "
                                f"artefact; only the guide bush "
                                f"('{GUIDE_BUSH_TOOL_POSITION}') is probed")
            if goal.c_angles_deg:
                raise PlanError("c_angles_deg: not used by the guide-bush cycle; leave empty")
            return plan_guide_bush_cycle(self.geometry,
                                         goal.points_per_indexing or DEFAULT_GUIDE_BUSH_REPEATS,
                                         self.guide_bush_timing)
        raise PlanError(f"artefact: unknown artefact {goal.artefact!r} "
                        f"(0 = sphere, 1 = guide bush)")

    def timeout_for(self, goal: GoalSpec) -> float:
        t = goal.timeout_s
        if not math.isfinite(t) or t < 0:
            raise PlanError(f"timeout_s: {t!r} must be >= 0 (0 = default)")
        return t if t > 0 else self.default_timeout_s

    # ------------------------------------------------------------------ running
    def run(self, goal: GoalSpec, backend: ProbeBackend,
            on_point: PointCallback | None = None,
            cancel_requested: Callable[[], bool] | None = None) -> CycleResult:
        try:
            plan = self.plan(goal)
            timeout = self.timeout_for(goal)
        except PlanError as exc:
            return failure(f"invalid goal: {exc}")
        ex = execute_plan(plan, backend, timeout, on_point, cancel_requested)
        if ex.failure is not None:
            stamps = [r.stamp_s for r in ex.replies]
            return failure(ex.failure, duration_s=ex.elapsed_s, points_done=len(ex.replies),
                           stamp_s=stamps[-1] if stamps else math.nan,
                           details={"canceled": ex.canceled})
        if plan.artefact == ARTEFACT_SPHERE:
            result, new_ref = evaluate_sphere_cycle(
                plan, ex.replies, self.limits, self.references.sphere, goal.set_reference,
                self.geometry.sphere.d_m)
            if new_ref is not None:
                self.references.sphere = new_ref
        else:
            result, new_ref = evaluate_guide_bush_cycle(
                plan, ex.replies, self.limits, self.guide_bush_point_sigma_um,
                self.references.guide_bush.get(GUIDE_BUSH_TOOL_POSITION), goal.set_reference,
                GUIDE_BUSH_COMPONENT)
            if new_ref is not None:
                self.references.guide_bush[GUIDE_BUSH_TOOL_POSITION] = new_ref
        result = dataclasses.replace(result, duration_s=max(result.duration_s, ex.elapsed_s))
        if new_ref is not None and self.reference_path:
            self.references.save(self.reference_path)
        return result
