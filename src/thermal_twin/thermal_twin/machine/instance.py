"""Unit-to-unit variation: one machine of a type = the preset with its parameters perturbed
within stated tolerances, drawn from a seed.

A compensation model built from the nominal type (a prior) must be tested on a plant that is
*not* the nominal model; :func:`machine_instance` makes such a plant, reproducibly (the same
preset, seed and tolerances give the same machine). Every perturbation is a factor drawn
uniformly in [1 - tol, 1 + tol]; the tolerances are in :data:`TOLERANCES` (docs/prior.md says
where they come from). The instance keeps the preset's ``name`` (scenarios are keyed by it) and
says which unit it is in ``description`` and :func:`instance_label`. No rclpy here.
"""
from __future__ import annotations

import copy
import pathlib
from typing import Any, Mapping

import numpy as np
import yaml

from thermal_twin.machine.schema import _read_yaml, load_machine
from thermal_twin.machine.spec import MachineSpecError

#: Relative tolerances (half-width of the uniform factor) per parameter class.
TOLERANCES: dict[str, float] = {
    "capacity": 0.10,      # masses and specific heats of castings / weldments
    "conductance": 0.20,   # contact and convection coefficients (h scatters most)
    "per_unit": 0.20,      # speed / MWF dependent convection
    "coefficient": 0.15,   # motor and bearing losses (preload, motor batch)
    "error_gain": 0.10,    # effective lengths x expansion coefficient
}


def instance_label(preset: str, seed: int) -> str:
    """The name a demo prints for the unit: ``nmv5000 unit #seed``."""
    return f"{preset} unit #{seed}"


def _check_tolerances(tolerances: Mapping[str, float]) -> dict[str, float]:
    tol = dict(TOLERANCES)
    for k, v in tolerances.items():
        if k not in TOLERANCES:
            raise MachineSpecError(f"machine instance: tolerance {k!r} is not one of {sorted(TOLERANCES)}")
        try:
            ok = 0.0 <= float(v) < 1.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise MachineSpecError(f"machine instance: tolerance {k!r} = {v!r} must be in [0, 1)")
        tol[k] = float(v)
    return tol


def machine_instance(preset: str | pathlib.Path, seed: int,
                     tolerances: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The raw machine mapping of unit ``seed`` of ``preset`` (a preset name or a YAML path).

    Seed ``-1`` is refused: the nominal machine is the preset itself. The result validates with
    ``load_machine`` (checked here before it is returned).
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise MachineSpecError(f"machine instance: seed {seed!r} must be an integer >= 0")
    tol = _check_tolerances(tolerances or {})
    raw, _ = _read_yaml(str(preset))
    raw = copy.deepcopy(raw)
    rng = np.random.default_rng([seed, 0x5EED])

    def factor(kind: str) -> float:
        return float(1.0 + tol[kind] * rng.uniform(-1.0, 1.0))

    for name in sorted(raw.get("nodes", {})):
        raw["nodes"][name]["capacity"] = float(raw["nodes"][name]["capacity"]) * factor("capacity")
    for name in sorted(raw.get("links", {})):
        link = raw["links"][name]
        link["conductance"] = float(link.get("conductance", 0.0)) * factor("conductance")
        for inp in sorted(link.get("varies_with", {}) or {}):
            link["varies_with"][inp]["per_unit"] = float(link["varies_with"][inp]["per_unit"]) * factor("per_unit")
    for name in sorted(raw.get("sources", {})):
        for key in ("coefficient", "power"):     # input-driven losses or a constant power
            if isinstance(raw["sources"][name].get(key), (int, float)):
                raw["sources"][name][key] = float(raw["sources"][name][key]) * factor("coefficient")
    for name in sorted(raw.get("errors", {})):
        terms = raw["errors"][name]["terms"]
        for node in sorted(terms):
            terms[node] = float(terms[node]) * factor("error_gain")
    nominal = raw.get("name", str(preset))
    raw["description"] = (f"{instance_label(nominal, seed)}: {raw.get('description', nominal)}, "
                          f"parameters perturbed uniformly within "
                          + ", ".join(f"{k} +-{100 * v:g} %" for k, v in tol.items()))
    load_machine(raw)   # refuse an instance the twin would not run
    return raw


def write_instance(path: str | pathlib.Path, preset: str, seed: int,
                   tolerances: Mapping[str, float] | None = None) -> pathlib.Path:
    """Write unit ``seed`` of ``preset`` as a machine YAML file (for ``--machine FILE``)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = machine_instance(preset, seed, tolerances)
    path.write_text(f"# {raw['description']}\n" + yaml.safe_dump(raw, sort_keys=False))
    return path
