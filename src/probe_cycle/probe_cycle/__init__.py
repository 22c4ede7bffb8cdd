"""ProbeCycle: the probing cycle of a 5-axis machine (sphere) and of a Swiss-type lathe (guide
bush) as a ROS-free engine with backends (artefact model, CNC over OPC UA); the action server
and the twin backend (ROS) live in ``probe_cycle_node`` and ``twin_backend``. See README.md."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "probe_cycle_engine": ["GoalSpec", "ProbeCycleEngine"],
    "cycle_plan": ["CyclePlan", "PlanError", "plan_guide_bush_cycle", "plan_sphere_cycle"],
    "cycle_result": ["CycleLimits", "CycleResult", "MeasuredErrors"],
    "cycle_reference": ["ReferenceFileError", "ReferenceStore"],
    "probe_backend": ["ArtefactModelBackend", "ProbeBackend", "ProbeBackendError", "TouchReply"],
    "cnc_probe_backend": ["CncProbeBackend", "CncProbeNodes"],
    "sphere_fit": ["SphereFit", "SphereFitError", "fit_sphere_centre"],
    "location_equations": ["location_errors"],
})
