"""The validated machine description of the twin: one frozen record per schema item.

``machine_validation`` builds these from YAML; the network, sensor model and error map read
them. The YAML schema itself is described in docs/twin.md ("Machine YAML").
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

SCHEMA_VERSION = 1
UNITS = {"temperature": "degC", "time": "s", "capacity": "J/K", "conductance": "W/K",
         "power": "W", "error_linear": "um", "error_angular": "um/m"}
ERROR_UNITS = ("um", "um/m")
INPUT_KINDS = ("machine", "environment")
#: the input a following boundary is lowered to: ``<boundary>_follows`` (physics.boundary_follow)
FOLLOW_SUFFIX = "_follows"


class MachineSpecError(ValueError):
    """A machine description is invalid; the message names the key path and the value."""


@dataclass(frozen=True)
class InputSpec:
    name: str
    kind: str
    unit: str
    default: float
    min: float
    max: float
    from_sensor: str | None


@dataclass(frozen=True)
class FollowSpec:
    """A boundary that follows another temperature instead of holding its own (a chiller
    tracking the hall): ``T = offset + gain * lag(T_followed)``, a first-order lag of time
    constant ``tau_s`` (0: none). ``temperature`` names an input or a boundary that does not
    itself follow."""

    temperature: str
    gain: float
    offset: float
    tau_s: float


@dataclass(frozen=True)
class BoundarySpec:
    name: str
    temperature: float | str | None   # constant degC or an input name; None when it follows
    follows: FollowSpec | None = None


@dataclass(frozen=True)
class NodeSpec:
    name: str
    capacity: float


@dataclass(frozen=True)
class LinkSpec:
    name: str
    a: str
    b: str
    conductance: float
    varies_with: tuple[tuple[str, float, float], ...]   # (input, per_unit, exponent)


@dataclass(frozen=True)
class SourceSpec:
    name: str
    node: str
    power: float
    input: str | None
    coefficient: float
    exponent: float
    periodic_amplitude: float
    periodic_period_s: float
    periodic_phase_s: float


@dataclass(frozen=True)
class SensorSpec:
    name: str
    weights: tuple[tuple[str, float], ...]   # (node or boundary, weight)
    noise_std: float
    resolution: float
    lag_s: float
    bias: float
    gain: float
    position_mm: tuple[float, float, float] | None = None
    drift_k_per_h: float = 0.0               # slow linear drift of the reading since t = 0 of the clock

    @property
    def column(self) -> str:
        return f"{self.name}_c"


@dataclass(frozen=True)
class ErrorSpec:
    name: str
    unit: str
    offset: float
    terms: tuple[tuple[str, float], ...]      # (node, gain per K)


@dataclass
class Machine:
    """A validated machine description (schema: docs/twin.md, "Machine YAML")."""

    name: str
    description: str
    inputs: dict[str, InputSpec]
    boundaries: dict[str, BoundarySpec]
    nodes: dict[str, NodeSpec]
    links: dict[str, LinkSpec]
    sources: dict[str, SourceSpec]
    sensors: dict[str, SensorSpec]
    errors: dict[str, ErrorSpec]
    initial_state: str | dict
    spec: dict = field(repr=False)
    source_path: str = ""

    def to_dict(self) -> dict:
        """A deep copy of the normalised description, to edit and load again."""
        return copy.deepcopy(self.spec)

    @property
    def node_names(self) -> list[str]:
        return list(self.nodes)

    @property
    def sensor_ids(self) -> list[str]:
        return list(self.sensors)

    @property
    def error_names(self) -> list[str]:
        return list(self.errors)

    def machine_inputs(self) -> list[str]:
        return [n for n, s in self.inputs.items() if s.kind == "machine"]
