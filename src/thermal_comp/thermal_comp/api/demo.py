"""A small cell to try the API on: the 5-axis twin, its sensors, probing, model, frames and bridge.

The twin runs in lock-step with the sensors, the model and the bridge (docs/architecture.md),
at most ``real_time_factor`` simulated seconds per wall second: simulated time stands still
while a node is behind, so a probing cycle's timeout (simulated seconds) measures the cycle and
not how busy the computer is. No recorder: a script reads what it needs through the API.
"""
from __future__ import annotations

import math
from typing import Any


def demo_cell(name: str = "api_demo", domain_id: int | None = None, hours: float = 48.0,
              real_time_factor: float = 600.0, seed: int = 0) -> dict[str, Any]:
    """The cell document (the format of ``thermal-comp launch`` files) of the small demo cell;
    ``domain_id`` None: the environment's ROS_DOMAIN_ID."""
    if not (math.isfinite(hours) and 0 < hours <= 178):
        raise ValueError(f"hours: {hours!r} is not in (0, 178] (the scenario's length)")
    if not (math.isfinite(real_time_factor) and real_time_factor > 0):
        raise ValueError(f"real_time_factor: {real_time_factor!r} is not a finite number > 0")
    cell: dict[str, Any] = {"cell": name, "use_sim_time": True, "nodes": [
        {"name": "machine_sim", "module": "thermal_twin.machine_sim_node",
         "parameters": {"machine": "nmv5000", "scenario": "talc-178h-dry", "hours": float(hours),
                        "step_s": 300.0, "seed": int(seed), "real_time_factor": float(real_time_factor),
                        "lockstep_participants": ["sensors", "model", "bridge"]}},
        {"name": "sensors", "module": "thermal_sensors.temperature_publisher_node",
         "parameters": {"source": "twin", "sensor_config": "nmv5000", "lockstep_participant": True}},
        {"name": "probe_cycle", "module": "probe_cycle.probe_cycle_node", "parameters": {"backend": "twin"}},
        {"name": "model", "module": "talc_model.talc_model_node",
         "parameters": {"model_kind": "talc", "artefact": "sphere", "lockstep_participant": True}},
        {"name": "static_frames", "module": "thermal_comp.frames.static_frames_node",
         "parameters": {"machine": "nmv5000"}},
        {"name": "bridge", "module": "cnc_bridge.cnc_bridge_node", "lifecycle": True,
         "parameters": {"backend": "twin", "lockstep": True, "compensation_mode": "kinematic",
                        "abs_limit_um": 50.0}},
    ]}
    if domain_id is not None:
        cell["domain_id"] = int(domain_id)
    return cell
