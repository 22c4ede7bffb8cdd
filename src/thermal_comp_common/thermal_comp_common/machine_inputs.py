"""MachineState as the flat numeric inputs the models see (no rclpy: any object with the
MachineState fields works, an rclpy message or a message decoded from a bag)."""
from __future__ import annotations

from typing import Any


def machine_state_inputs(msg: Any) -> dict[str, float]:
    """``<spindle>_rpm``, ``<rotary>_axis_rpm``, ``<axis>_pos``, ``<drive>_power_w``,
    ``coolant_on``, ``coolant_temperature_degc``, ``door_open``, ``machine_busy_probing``."""
    out: dict[str, float] = {}
    for n, v in zip(msg.spindle_names, msg.spindle_speeds_rpm):
        out[f"{n}_rpm"] = float(v)
    for n, v in zip(msg.rotary_axis_names, msg.rotary_axis_speeds_rpm):
        out[f"{n}_axis_rpm"] = float(v)
    for n, v in zip(msg.axis_names, msg.axis_positions):
        out[f"{n}_pos"] = float(v)
    for n, v in zip(msg.drive_names, msg.drive_powers_w):
        out[f"{n}_power_w"] = float(v)
    out["coolant_on"] = 1.0 if msg.coolant_on else 0.0
    out["coolant_temperature_degc"] = float(msg.coolant_temperature_degc)
    out["door_open"] = 1.0 if msg.door_open else 0.0
    out["machine_busy_probing"] = 1.0 if msg.machine_busy_probing else 0.0
    return out
