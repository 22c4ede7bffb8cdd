"""TALC's inputs from the machine type: the soft sensors of the type's nominal twin
(:mod:`thermal_twin.sim.type_soft_sensors`) named ``twin:<node>`` or ``twin:<error>`` in
``TalcConfig.input_names``, the type named by ``TalcConfig.type_model`` (preset name or YAML
path). TALC steps them once per :meth:`update_inputs` instant and adds their values to the
signals its inputs are read from; their state is part of TALC's persisted state. :func:`load_soft_sensors` and
:func:`restore_soft_sensors` serve the characteristic-diagram model too (``CdConfig.type_inputs``).
docs/talc.md, "The machine type's physics as TALC's inputs". No rclpy here.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

from thermal_twin.machine.spec import MachineSpecError
from thermal_twin.sim.type_soft_sensors import PREFIX, TypeSoftSensors

from talc_model.talc.config import TalcConfig, parse_input


def twin_signal_names(input_names: list[str]) -> list[str]:
    """The soft-sensor signals (``twin:...``) that TALC inputs read (factors of products and
    both sides of differences included)."""
    out = []
    for name in input_names:
        for factor in name.split(" * "):
            out += [s for s in parse_input(factor) if s is not None and s.startswith(PREFIX)]
    return list(dict.fromkeys(out))


def soft_sensors_for(config: TalcConfig) -> TypeSoftSensors | None:
    """The type's soft sensors for ``config`` (None without ``type_model``); an input naming a
    soft sensor the type does not have, or one without ``type_model``, raises ValueError."""
    wanted = twin_signal_names(config.input_names)
    named = wanted + twin_signal_names(config.type_input_names)
    if not config.type_model:
        if named:
            raise ValueError(f"TALC config 'input_names' / 'type_input_names': {named} are soft sensors of the "
                             "machine type, but 'type_model' names no type (a preset name or a machine YAML)")
        return None
    sensors = load_soft_sensors(config.type_model, named, "TALC config", "'input_names' / 'type_input_names'")
    return sensors if wanted else None     # stepped only when the model's own inputs read it


def load_soft_sensors(type_model: str, names: Sequence[str], where: str, field: str) -> TypeSoftSensors:
    """The soft sensors of the type ``type_model`` (preset name or machine YAML); every one of
    ``names`` must be among them. A bad type or name raises ValueError naming ``where`` (e.g.
    "TALC config", "cd config") and ``field`` (the key that named them). Used by TALC and the CD model."""
    try:
        sensors = TypeSoftSensors(type_model)
    except (MachineSpecError, OSError, ValueError) as exc:
        raise ValueError(f"{where} 'type_model': {type_model!r}: {exc}") from None
    unknown = [n for n in names if n not in sensors.names]
    if unknown:
        raise ValueError(f"{where} {field}: {unknown} are not soft sensors of the "
                         f"type {sensors.machine.name!r} (it has {sensors.names})")
    return sensors


def restore_soft_sensors(sensors: TypeSoftSensors | None, state: Mapping[str, Any]) -> str:
    """Resume ``sensors`` from a TALC ``state``; returns a note for the model's message when the
    state has none (saved before the soft sensors: they start steady at the next instant)."""
    if sensors is None:
        return ""
    saved = state.get("soft_sensors")
    if saved is None:
        return (f"; the state has no soft sensors of {sensors.machine.name}: they start at the type's steady "
                "state of the next instant")
    sensors.restore(saved)
    return ""


def held_input_labels(sensors: TypeSoftSensors | None) -> list[str]:
    """The soft sensors' inputs held at the last instant, as the ModelStatus lists them
    (``excluded_sensor_ids``: "<input> (type twin input, held)"); [] without soft sensors."""
    return [f"{n} (type twin input, held)" for n in (sensors.held_now if sensors is not None else [])]
