"""How the twin's inputs and errors map onto the ROS messages (pure, no rclpy).

Naming convention of machine inputs (documented in docs/twin.md):
- ``<a>_speed_rpm`` with a one-letter axis name ``a``: rotary-axis speed of axis ``A``
  (``c_speed_rpm`` -> rotary axis "C");
- any other ``<name>_rpm``: a spindle (``s1_rpm`` -> "s1", ``spindle_rpm`` -> "spindle");
- ``<name>_w``: drive power of drive ``name``;
- ``coolant_on`` / ``oil_on``: fluid flowing; ``coolant_temp_degc`` / ``oil_temp_degc``:
  its supply temperature; ``door_open``: working-space door.
Error names: ``E_*`` keep their name; ``*_um`` drop the suffix (``GB_X_um`` -> ``GB_X``).
"""
from __future__ import annotations

import math
from typing import Mapping

UNIT_UM = 0          # ThermalErrors.UNIT_UM
UNIT_UM_PER_M = 1    # ThermalErrors.UNIT_UM_PER_M


def machine_state_fields(inputs: Mapping[str, float]) -> dict:
    spindles, rotary, drives = [], [], []
    coolant_on, coolant_t, door = False, math.nan, False
    for name, v in inputs.items():
        if name.endswith("_speed_rpm") and len(name) == len("x_speed_rpm"):
            rotary.append((name[0].upper(), float(v)))
        elif name.endswith("_rpm"):
            spindles.append((name[: -len("_rpm")], float(v)))
        elif name.endswith("_w"):
            drives.append((name[: -len("_w")], float(v)))
        elif name in ("coolant_on", "oil_on"):
            coolant_on = coolant_on or v >= 0.5
        elif name in ("coolant_temp_degc", "oil_temp_degc"):
            coolant_t = float(v)
        elif name == "door_open":
            door = v >= 0.5
    return {
        "spindle_names": [n for n, _ in spindles], "spindle_speeds_rpm": [v for _, v in spindles],
        "rotary_axis_names": [n for n, _ in rotary], "rotary_axis_speeds_rpm": [v for _, v in rotary],
        "drive_names": [n for n, _ in drives], "drive_powers_w": [v for _, v in drives],
        "coolant_on": bool(coolant_on), "coolant_temperature_degc": coolant_t, "door_open": bool(door),
    }


def message_input_name(name: str) -> str:
    """The name under which a twin input ``name`` reaches a model through the MachineState
    message (:func:`machine_state_fields`, then ``machine_inputs.machine_state_inputs``):
    ``c_speed_rpm`` -> ``C_axis_rpm``, ``<d>_w`` -> ``<d>_power_w``, ``coolant_temp_degc`` /
    ``oil_temp_degc`` -> ``coolant_temperature_degc``, ``oil_on`` -> ``coolant_on``; spindles and
    the rest keep their name. (A replay of a recording gives the twin's own names.)"""
    if name.endswith("_speed_rpm") and len(name) == len("x_speed_rpm"):
        return f"{name[0].upper()}_axis_rpm"
    if name.endswith("_w"):
        return f"{name[: -len('_w')]}_power_w"
    if name in ("coolant_temp_degc", "oil_temp_degc"):
        return "coolant_temperature_degc"
    if name == "oil_on":
        return "coolant_on"
    return name


def component_name(error_name: str) -> str:
    return error_name[: -len("_um")] if error_name.endswith("_um") else error_name


def error_components(errors: Mapping[str, float], units: Mapping[str, str]) -> tuple[list, list, list]:
    """(component names, values, ThermalErrors unit codes) of the twin's errors."""
    names, values, codes = [], [], []
    for e, v in errors.items():
        names.append(component_name(e))
        values.append(float(v))
        codes.append(UNIT_UM_PER_M if units[e] == "um/m" else UNIT_UM)
    return names, values, codes
