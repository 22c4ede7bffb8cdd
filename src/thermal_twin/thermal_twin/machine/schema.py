"""Machine YAML of the thermal twin: load (path, text, mapping or preset name), save and dump.

A machine is a lumped-parameter thermal network, a sensor model and a thermo-elastic error
map, each item keyed by name so that a program (the mismatch finder) can change one item with
a one-line diff. The schema is described in docs/twin.md ("Machine YAML"); the records live in
``machine_spec`` and the checks in ``machine_validation``.
"""
from __future__ import annotations

import copy
import pathlib
import re
from typing import Any, Mapping

import yaml

from thermal_twin.machine.spec import (ERROR_UNITS, INPUT_KINDS, SCHEMA_VERSION, UNITS, BoundarySpec,
                                       ErrorSpec, FollowSpec, InputSpec, LinkSpec, Machine, MachineSpecError,
                                       NodeSpec, SensorSpec, SourceSpec)
from thermal_twin.machine.validation import validate_machine
from thermal_twin.machine.presets import preset_path

__all__ = ["SCHEMA_VERSION", "UNITS", "ERROR_UNITS", "INPUT_KINDS", "MachineSpecError", "Machine",
           "InputSpec", "BoundarySpec", "FollowSpec", "NodeSpec", "LinkSpec", "SourceSpec", "SensorSpec", "ErrorSpec",
           "load_machine", "save_machine", "dump_machine", "SECTIONS"]

SECTIONS = ("inputs", "boundaries", "nodes", "links", "sources", "sensors", "errors")


class _Loader(yaml.SafeLoader):
    """Safe loader that reads YAML 1.2 floats such as ``2.5e4`` (PyYAML's 1.1 rules make
    them strings, a trap for people writing machine files by hand)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                   |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


def load_machine(source: str | pathlib.Path | Mapping) -> Machine:
    """Validate a machine description given as a YAML path, YAML text or a mapping.

    A bare preset name (``nmv5000``) is looked up among the packaged presets.
    """
    path = ""
    if isinstance(source, Mapping):
        raw = copy.deepcopy(dict(source))
    else:
        raw, path = _read_yaml(str(source))
    try:
        m = validate_machine(raw)
    except MachineSpecError as exc:
        if path:
            raise MachineSpecError(f"{path}: {exc}") from None
        raise
    m.source_path = path
    return m


def _read_yaml(text_or_path: str) -> tuple[dict, str]:
    """(raw mapping, file path or '') of YAML text, a file path or a preset name."""
    path = ""
    p = pathlib.Path(text_or_path)
    if "\n" not in text_or_path and not p.suffix and not p.exists():
        p = preset_path(text_or_path)
    if "\n" in text_or_path:
        content = text_or_path
    else:
        if not p.is_file():
            raise MachineSpecError(f"{p}: no such machine file")
        content = p.read_text()
        path = str(p)
    try:
        raw = yaml.load(content, Loader=_Loader)
    except yaml.YAMLError as exc:
        raise MachineSpecError(f"{path or 'machine YAML'}: not valid YAML: {exc}") from None
    if not isinstance(raw, Mapping):
        raise MachineSpecError(f"{path or 'machine YAML'}: top level must be a mapping, got {raw!r:.60}")
    return dict(raw), path


def save_machine(machine: Machine | Mapping, path: str | pathlib.Path) -> None:
    """Validate and write a machine description as YAML (keys in schema order)."""
    m = machine if isinstance(machine, Machine) else load_machine(machine)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(dump_machine(m))
    tmp.replace(path)


def dump_machine(machine: Machine) -> str:
    """YAML text of a machine, one flow mapping per item so a change is a one-line diff."""
    spec = machine.spec
    out = [f"schema_version: {spec['schema_version']}", f"name: {spec['name']}",
           "description: " + yaml.safe_dump(spec["description"], default_style='"', width=10**6).strip().removesuffix("\n..."),
           "units: " + _flow(spec["units"]),
           "initial_state: " + (_flow(spec["initial_state"]) if isinstance(spec["initial_state"], dict)
                                else str(spec["initial_state"]))]
    for section in SECTIONS:
        items = spec.get(section) or {}
        out.append(f"{section}:" + ("" if items else " {}"))
        for k, v in items.items():
            out.append(f"  {k}: {_flow(v)}")
    if spec.get("contacts"):
        out.append("contacts: " + _flow(spec["contacts"]))
    if spec.get("calibration"):
        out.append("calibration: " + _flow(spec["calibration"]))
    return "\n".join(out) + "\n"


def _flow(v: Any) -> str:
    return yaml.safe_dump(v, default_flow_style=True, width=10**6, sort_keys=False).strip()
