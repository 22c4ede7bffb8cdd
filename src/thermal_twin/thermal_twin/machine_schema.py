"""Declarative machine description (YAML) of the thermal twin: schema, validation, loading.

A machine is a lumped-parameter thermal network plus a sensor model and a thermo-elastic
error map. Units are fixed (SI plus the usual machine-tool units) and stated in the file
under ``units`` for the reader; a file that declares other units is rejected.

Schema (``schema_version: 1``); every mapping is keyed by a name, so that a program (the
mismatch finder) can add or alter one item with a one-line, diff-able change::

    schema_version: 1
    name: nmv5000                      # identifier
    description: free text
    units: {temperature: degC, time: s, capacity: J/K, conductance: W/K, power: W,
            error_linear: um, error_angular: um/m}
    inputs:                            # time-varying signals of a scenario (CSV input columns)
      c_speed_rpm: {kind: machine, unit: 1/min, default: 0, min: 0, max: 1200}
      coolant_on:  {kind: machine, unit: bool, default: 0}
      ambient_degc: {kind: environment, unit: degC, default: 20, from_sensor: ambient}
        # kind: machine (an operating input of the machine) or environment (a boundary
        # condition such as the hall temperature); from_sensor: the sensor whose reading
        # stands in for this input when a recording lacks the column (real data)
    boundaries:                        # external temperatures (infinite heat reservoirs)
      ambient: {temperature: ambient_degc}    # an input name or a constant in degC
      c_cooling: {temperature: 21.0}
    initial_state: steady              # steady (equilibrium of the idle machine - machine
                                       # inputs at their defaults except boundary temperatures -
                                       # with its environment at t=0) or
                                       # {boundary: ambient} (every node at that temperature)
    nodes:                             # lumped bodies: heat capacity C [J/K]
      table: {capacity: 2.0e5}
    links:                             # conductances [W/K] node-node or node-boundary
      table_air:
        between: [table, ambient]
        conductance: 4.0               # base value G0 >= 0
        varies_with:                   # G = G0 + sum(per_unit * |input|**exponent)
          c_speed_rpm: {per_unit: 0.02, exponent: 0.8}   # forced convection of rotation
          door_open: {per_unit: 10}                        # door open: raised convection
    sources:                           # heat input [W] into a node
      c_motor_losses:
        node: c_motor
        power: 0.0                     # constant part P0 [W]
        input: c_speed_rpm             # optional: P += coefficient * |input|**exponent
        coefficient: 0.002
        exponent: 1.5
        periodic: {amplitude: 0.0, period_s: 86400, phase_s: 0}   # optional, P += A sin(2 pi (t - phase)/period)
    sensors:                           # CSV column <id>_c; reading in degC
      ambient: {of: ambient}           # a node or boundary name, or weights
      c_delta: {of: {c_coolant_out: 1.0, c_cooling: -1.0}}   # weighted sum (placement, differences)
        # options: noise_std [K] (default 0), resolution [K] (quantisation, 0 = none),
        # lag_s (first-order sensor time constant, 0 = none), bias [K], gain (default 1),
        # position_mm [x, y, z] (where it sits, machine coordinates; for viewers only)
    errors:                            # thermo-elastic map: error = offset + sum(g * (T - T_ref))
      E_Y0C: {unit: um, terms: {table: 3.0, column: -6.5}}   # um per K (um/m per K if angular)
        # T_ref is each node's temperature at t = 0; options: offset, unit um | um/m

Validation raises :class:`MachineSpecError` with the key path and the bad value, e.g.
``nodes.table.capacity: -5.0 must be > 0``. The validated machine keeps its normalised
dictionary (:attr:`Machine.spec`); edit a copy (:meth:`Machine.to_dict`) and load it again
to change the physics, :func:`save_machine` writes it back as YAML.
"""
from __future__ import annotations

import copy
import math
import pathlib
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

import yaml

SCHEMA_VERSION = 1
UNITS = {"temperature": "degC", "time": "s", "capacity": "J/K", "conductance": "W/K",
         "power": "W", "error_linear": "um", "error_angular": "um/m"}
ERROR_UNITS = ("um", "um/m")
INPUT_KINDS = ("machine", "environment")
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


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
class BoundarySpec:
    name: str
    temperature: float | str          # constant degC or an input name


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
    """A validated machine description (see the module docstring for the schema)."""

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


# --------------------------------------------------------------------------------------
def _fail(path: str, value: Any, why: str) -> MachineSpecError:
    return MachineSpecError(f"{path}: {value!r} {why}")


def _mapping(value: Any, path: str, required: bool = True) -> dict:
    if value is None and not required:
        return {}
    if not isinstance(value, Mapping):
        raise _fail(path, value, "must be a mapping")
    return dict(value)


def _number(d: Mapping, key: str, path: str, default: Any = None, lo: float | None = None,
            lo_open: bool = False, hi: float | None = None) -> float:
    p = f"{path}.{key}" if path else key
    if key not in d:
        if default is None:
            raise MachineSpecError(f"{p}: missing (a number is required)")
        return float(default)
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _fail(p, v, "is not a number")
    v = float(v)
    if not math.isfinite(v):
        raise _fail(p, v, "is not finite")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise _fail(p, v, f"must be {'>' if lo_open else '>='} {lo:g}")
    if hi is not None and v > hi:
        raise _fail(p, v, f"must be <= {hi:g}")
    return v


def _check_keys(d: Mapping, allowed: set[str], path: str) -> None:
    for k in d:
        if k not in allowed:
            raise _fail(f"{path}.{k}" if path else str(k), d[k],
                        f"is not a known key here (allowed: {', '.join(sorted(allowed))})")


def _check_name(name: Any, path: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise _fail(path, name, "is not a valid name (letters, digits, '_', starting with a letter)")
    return name


def load_machine(source: str | pathlib.Path | Mapping) -> Machine:
    """Validate a machine description given as a YAML path, YAML text or a mapping.

    A bare preset name (``nmv5000``) is looked up among the packaged presets.
    """
    path = ""
    if isinstance(source, Mapping):
        raw = copy.deepcopy(dict(source))
    else:
        text_or_path = str(source)
        p = pathlib.Path(text_or_path)
        if "\n" not in text_or_path and not p.suffix and not p.exists():
            from thermal_twin.presets import preset_path
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
        raw = dict(raw)
    try:
        m = _validate(raw)
    except MachineSpecError as exc:
        if path:
            raise MachineSpecError(f"{path}: {exc}") from None
        raise
    m.source_path = path
    return m


def _validate(raw: dict) -> Machine:
    _check_keys(raw, {"schema_version", "name", "description", "units", "inputs", "boundaries",
                      "initial_state", "nodes", "links", "sources", "sensors", "errors"}, "")
    ver = raw.get("schema_version", SCHEMA_VERSION)
    if ver != SCHEMA_VERSION:
        raise _fail("schema_version", ver, f"is not supported (expected {SCHEMA_VERSION})")
    name = _check_name(raw.get("name"), "name")
    description = str(raw.get("description", ""))
    units = _mapping(raw.get("units"), "units", required=False)
    for k, v in units.items():
        if k not in UNITS:
            raise _fail(f"units.{k}", v, f"is not a known unit key (known: {', '.join(UNITS)})")
        if v != UNITS[k]:
            raise _fail(f"units.{k}", v, f"must be {UNITS[k]!r}: the twin uses fixed units")
    spec: dict[str, Any] = {"schema_version": SCHEMA_VERSION, "name": name,
                            "description": description, "units": dict(UNITS)}

    # inputs ------------------------------------------------------------------------
    inputs: dict[str, InputSpec] = {}
    spec["inputs"] = {}
    for iname, d in _mapping(raw.get("inputs"), "inputs", required=False).items():
        p = f"inputs.{iname}"
        _check_name(iname, p)
        if iname.endswith("_c") or iname.startswith("E_") or iname.endswith("_um") or iname == "time_s":
            raise _fail(p, iname, "clashes with the recording CSV column classes "
                        "(names ending in _c are sensors, E_*/..._um are errors)")
        d = _mapping(d, p)
        _check_keys(d, {"kind", "unit", "default", "min", "max", "from_sensor"}, p)
        kind = d.get("kind", "machine")
        if kind not in INPUT_KINDS:
            raise _fail(f"{p}.kind", kind, f"must be one of {list(INPUT_KINDS)}")
        lo = _number(d, "min", p, default=-math.inf) if "min" in d else -math.inf
        hi = _number(d, "max", p, default=math.inf) if "max" in d else math.inf
        if lo > hi:
            raise _fail(f"{p}.max", hi, f"is below min {lo}")
        default = _number(d, "default", p, default=0.0)
        if not lo <= default <= hi:
            raise _fail(f"{p}.default", default, f"is outside [{lo}, {hi}]")
        fs = d.get("from_sensor")
        if fs is not None:
            _check_name(fs, f"{p}.from_sensor")
        inputs[iname] = InputSpec(iname, kind, str(d.get("unit", "")), default, lo, hi, fs)
        spec["inputs"][iname] = {k: d[k] for k in ("kind", "unit", "default", "min", "max",
                                                   "from_sensor") if k in d}

    # boundaries --------------------------------------------------------------------
    boundaries: dict[str, BoundarySpec] = {}
    spec["boundaries"] = {}
    for bname, d in _mapping(raw.get("boundaries"), "boundaries").items():
        p = f"boundaries.{bname}"
        _check_name(bname, p)
        d = _mapping(d, p)
        _check_keys(d, {"temperature"}, p)
        t = d.get("temperature")
        if isinstance(t, str):
            if t not in inputs:
                raise _fail(f"{p}.temperature", t, f"is not a declared input (inputs: {', '.join(inputs)})")
            temp: float | str = t
        else:
            temp = _number(d, "temperature", p, lo=-273.15)
        boundaries[bname] = BoundarySpec(bname, temp)
        spec["boundaries"][bname] = {"temperature": temp}
    if not boundaries:
        raise _fail("boundaries", {}, "must name at least one boundary (e.g. ambient)")

    # nodes --------------------------------------------------------------------------
    nodes: dict[str, NodeSpec] = {}
    spec["nodes"] = {}
    for nname, d in _mapping(raw.get("nodes"), "nodes").items():
        p = f"nodes.{nname}"
        _check_name(nname, p)
        if nname in boundaries:
            raise _fail(p, nname, "is also a boundary name; names must be unique")
        d = _mapping(d, p)
        _check_keys(d, {"capacity", "note"}, p)
        nodes[nname] = NodeSpec(nname, _number(d, "capacity", p, lo=0.0, lo_open=True))
        spec["nodes"][nname] = dict(d)
    if not nodes:
        raise _fail("nodes", {}, "must contain at least one node")
    places = set(nodes) | set(boundaries)

    # initial state --------------------------------------------------------------------
    init = raw.get("initial_state", "steady")
    if isinstance(init, Mapping):
        _check_keys(init, {"boundary"}, "initial_state")
        if init.get("boundary") not in boundaries:
            raise _fail("initial_state.boundary", init.get("boundary"), "is not a boundary")
        init = {"boundary": init["boundary"]}
    elif init != "steady":
        raise _fail("initial_state", init, "must be 'steady' or {boundary: NAME}")
    spec["initial_state"] = init

    # links --------------------------------------------------------------------------
    links: dict[str, LinkSpec] = {}
    spec["links"] = {}
    for lname, d in _mapping(raw.get("links"), "links", required=False).items():
        p = f"links.{lname}"
        _check_name(lname, p)
        d = _mapping(d, p)
        _check_keys(d, {"between", "conductance", "varies_with", "note"}, p)
        between = d.get("between")
        if not isinstance(between, (list, tuple)) or len(between) != 2:
            raise _fail(f"{p}.between", between, "must be a list of two node/boundary names")
        a, b = between
        for j, x in enumerate((a, b)):
            if x not in places:
                raise _fail(f"{p}.between[{j}]", x, "is not a node or boundary")
        if a == b:
            raise _fail(f"{p}.between", between, "links a place to itself")
        if a not in nodes and b not in nodes:
            raise _fail(f"{p}.between", between, "links two boundaries (at least one must be a node)")
        g0 = _number(d, "conductance", p, lo=0.0)
        vw = []
        vspec = {}
        for iname, t in _mapping(d.get("varies_with"), f"{p}.varies_with", required=False).items():
            q = f"{p}.varies_with.{iname}"
            if iname not in inputs:
                raise _fail(q, iname, f"is not a declared input (inputs: {', '.join(inputs)})")
            t = _mapping(t, q)
            _check_keys(t, {"per_unit", "exponent"}, q)
            vw.append((iname, _number(t, "per_unit", q, lo=0.0), _number(t, "exponent", q, default=1.0, lo=0.0)))
            vspec[iname] = dict(t)
        links[lname] = LinkSpec(lname, a, b, g0, tuple(vw))
        spec["links"][lname] = {k: v for k, v in d.items() if k != "varies_with"}
        spec["links"][lname]["between"] = [a, b]
        if vspec:
            spec["links"][lname]["varies_with"] = vspec

    # sources ------------------------------------------------------------------------
    sources: dict[str, SourceSpec] = {}
    spec["sources"] = {}
    for sname, d in _mapping(raw.get("sources"), "sources", required=False).items():
        p = f"sources.{sname}"
        _check_name(sname, p)
        d = _mapping(d, p)
        _check_keys(d, {"node", "power", "input", "coefficient", "exponent", "periodic", "note"}, p)
        node = d.get("node")
        if node not in nodes:
            raise _fail(f"{p}.node", node, "is not a node")
        power = _number(d, "power", p, default=0.0)
        inp = d.get("input")
        if inp is not None and inp not in inputs:
            raise _fail(f"{p}.input", inp, f"is not a declared input (inputs: {', '.join(inputs)})")
        coef = _number(d, "coefficient", p, default=0.0)
        if inp is None and coef != 0.0:
            raise _fail(f"{p}.coefficient", coef, "needs an 'input' to multiply")
        expo = _number(d, "exponent", p, default=1.0, lo=0.0)
        per = _mapping(d.get("periodic"), f"{p}.periodic", required=False)
        _check_keys(per, {"amplitude", "period_s", "phase_s"}, f"{p}.periodic")
        amp = _number(per, "amplitude", f"{p}.periodic", default=0.0) if per else 0.0
        period = _number(per, "period_s", f"{p}.periodic", lo=0.0, lo_open=True) if per else 86400.0
        phase = _number(per, "phase_s", f"{p}.periodic", default=0.0) if per else 0.0
        sources[sname] = SourceSpec(sname, node, power, inp, coef, expo, amp, period, phase)
        spec["sources"][sname] = dict(d)

    # sensors ------------------------------------------------------------------------
    sensors: dict[str, SensorSpec] = {}
    spec["sensors"] = {}
    for sid, d in _mapping(raw.get("sensors"), "sensors", required=False).items():
        p = f"sensors.{sid}"
        _check_name(sid, p)
        d = _mapping(d, p)
        _check_keys(d, {"of", "noise_std", "resolution", "lag_s", "bias", "gain", "position_mm", "note"}, p)
        pos = d.get("position_mm")
        if pos is not None:
            if (not isinstance(pos, (list, tuple)) or len(pos) != 3
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                               for v in pos)):
                raise _fail(f"{p}.position_mm", pos, "must be [x, y, z] in mm (three finite numbers)")
            pos = tuple(float(v) for v in pos)
        of = d.get("of")
        if isinstance(of, str):
            weights = ((of, 1.0),)
        elif isinstance(of, Mapping) and of:
            weights = tuple((k, _number(of, k, f"{p}.of")) for k in of)
        else:
            raise _fail(f"{p}.of", of, "must be a node/boundary name or a mapping name -> weight")
        for k, _ in weights:
            if k not in places:
                raise _fail(f"{p}.of", k, "is not a node or boundary")
        sensors[sid] = SensorSpec(sid, weights, _number(d, "noise_std", p, default=0.0, lo=0.0),
                                  _number(d, "resolution", p, default=0.0, lo=0.0),
                                  _number(d, "lag_s", p, default=0.0, lo=0.0),
                                  _number(d, "bias", p, default=0.0),
                                  _number(d, "gain", p, default=1.0), pos)
        spec["sensors"][sid] = dict(d)
    for iname, ispec in inputs.items():
        if ispec.from_sensor is not None and ispec.from_sensor not in sensors:
            raise _fail(f"inputs.{iname}.from_sensor", ispec.from_sensor, "is not a sensor")

    # errors -------------------------------------------------------------------------
    errors: dict[str, ErrorSpec] = {}
    spec["errors"] = {}
    for ename, d in _mapping(raw.get("errors"), "errors", required=False).items():
        p = f"errors.{ename}"
        if not isinstance(ename, str) or not (ename.startswith("E_") or ename.endswith("_um")):
            raise _fail(p, ename, "must be named E_* or *_um (recording CSV error columns)")
        d = _mapping(d, p)
        _check_keys(d, {"unit", "offset", "terms", "note"}, p)
        unit = d.get("unit", "um")
        if unit not in ERROR_UNITS:
            raise _fail(f"{p}.unit", unit, f"must be one of {list(ERROR_UNITS)}")
        terms = _mapping(d.get("terms"), f"{p}.terms")
        tt = []
        for node, g in terms.items():
            if node not in nodes:
                raise _fail(f"{p}.terms", node, "is not a node")
            tt.append((node, _number(terms, node, f"{p}.terms")))
        errors[ename] = ErrorSpec(ename, unit, _number(d, "offset", p, default=0.0), tuple(tt))
        spec["errors"][ename] = dict(d)
        spec["errors"][ename]["unit"] = unit
    return Machine(name, description, inputs, boundaries, nodes, links, sources, sensors, errors,
                   init, spec)


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
    for section in ("inputs", "boundaries", "nodes", "links", "sources", "sensors", "errors"):
        items = spec.get(section) or {}
        out.append(f"{section}:" + ("" if items else " {}"))
        for k, v in items.items():
            out.append(f"  {k}: {_flow(v)}")
    return "\n".join(out) + "\n"


def _flow(v: Any) -> str:
    return yaml.safe_dump(v, default_flow_style=True, width=10**6, sort_keys=False).strip()
