"""Validation of a raw machine description (a mapping read from YAML) into a :class:`Machine`.

One function per schema section, each returning its frozen records and its normalised part of
the description; every error is a :class:`MachineSpecError` naming the key path and the value,
e.g. ``nodes.table.capacity: -5.0 must be > 0``. A new section: its key in ``TOP_KEYS``, a
function here called from :func:`validate_machine`, a field of ``Machine`` and its name in
``machine_schema.SECTIONS`` (so that ``dump_machine`` writes it).
"""
from __future__ import annotations

import math
import re
from typing import Any, Iterator, Mapping

from thermal_twin.calibrate.bounds import check_section
from thermal_twin.machine.spec import (ERROR_UNITS, FOLLOW_SUFFIX, INPUT_KINDS, SCHEMA_VERSION, UNITS,
                                       BoundarySpec, ErrorSpec, FollowSpec, InputSpec, LinkSpec, Machine,
                                       MachineSpecError, NodeSpec, SensorSpec, SourceSpec)

TOP_KEYS = {"schema_version", "name", "description", "units", "inputs", "boundaries",
            "initial_state", "nodes", "links", "sources", "sensors", "errors", "calibration", "contacts"}
#: a sensor drifting faster than this is broken, not drifting
MAX_DRIFT_K_PER_H = 1.0
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


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


def _items(section: dict, name: str, allowed: set[str]) -> Iterator[tuple[str, str, dict]]:
    """(item name, key path, item mapping) of a section whose items are named mappings."""
    for item, d in section.items():
        p = f"{name}.{item}"
        _check_name(item, p)
        d = _mapping(d, p)
        _check_keys(d, allowed, p)
        yield item, p, d


def _declared_input(name: Any, inputs: Mapping, path: str) -> None:
    if name not in inputs:
        raise _fail(path, name, f"is not a declared input (inputs: {', '.join(inputs)})")


def validate_machine(raw: dict) -> Machine:
    """A :class:`Machine` from a raw description, or the first error found (sections in schema order)."""
    _check_keys(raw, TOP_KEYS, "")
    ver = raw.get("schema_version", SCHEMA_VERSION)
    if ver != SCHEMA_VERSION:
        raise _fail("schema_version", ver, f"is not supported (expected {SCHEMA_VERSION})")
    name = _check_name(raw.get("name"), "name")
    description = str(raw.get("description", ""))
    _units(_mapping(raw.get("units"), "units", required=False))
    spec: dict[str, Any] = {"schema_version": SCHEMA_VERSION, "name": name,
                            "description": description, "units": dict(UNITS)}
    inputs, spec["inputs"] = _inputs(_mapping(raw.get("inputs"), "inputs", required=False))
    boundaries, spec["boundaries"] = _boundaries(_mapping(raw.get("boundaries"), "boundaries"), inputs)
    nodes, spec["nodes"] = _nodes(_mapping(raw.get("nodes"), "nodes"), boundaries)
    places = set(nodes) | set(boundaries)
    init = spec["initial_state"] = _initial_state(raw.get("initial_state", "steady"), boundaries)
    links, spec["links"] = _links(_mapping(raw.get("links"), "links", required=False),
                                  nodes, places, inputs)
    sources, spec["sources"] = _sources(_mapping(raw.get("sources"), "sources", required=False),
                                        nodes, inputs)
    sensors, spec["sensors"] = _sensors(_mapping(raw.get("sensors"), "sensors", required=False), places)
    for iname, ispec in inputs.items():
        if ispec.from_sensor is not None and ispec.from_sensor not in sensors:
            raise _fail(f"inputs.{iname}.from_sensor", ispec.from_sensor, "is not a sensor")
    _check_initial_readings(init, sensors)
    errors, spec["errors"] = _errors(_mapping(raw.get("errors"), "errors", required=False), nodes)
    if raw.get("contacts") is not None:      # which places touch (the mismatch finder's new paths)
        spec["contacts"] = _contacts(raw["contacts"], nodes, boundaries)
    if raw.get("calibration") is not None:   # which parameters `calibrate` may move (checked there)
        spec["calibration"] = check_section(_mapping(raw["calibration"], "calibration"), spec)
    return Machine(name, description, inputs, boundaries, nodes, links, sources, sensors, errors,
                   init, spec)


def _contacts(section: Any, nodes: dict, boundaries: dict) -> list[list[str]]:
    """``contacts``: the pairs of places that physically touch (a joint, a fit, a bearing, a
    jacket's fluid on a node), ``[[a, b], ...]``; a node and a boundary or two nodes."""
    if not isinstance(section, list):
        raise _fail("contacts", section, "must be a list of [place, place] pairs")
    out: list[list[str]] = []
    seen: set = set()
    for i, pair in enumerate(section):
        p = f"contacts[{i}]"
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise _fail(p, pair, "must be a pair [place, place]")
        for j, x in enumerate(pair):
            if x not in nodes and x not in boundaries:
                raise _fail(f"{p}[{j}]", x, f"is not a node or boundary (nodes: {', '.join(nodes)}; "
                            f"boundaries: {', '.join(boundaries)})")
        if pair[0] == pair[1]:
            raise _fail(p, list(pair), "puts a place in contact with itself")
        if pair[0] in boundaries and pair[1] in boundaries:
            raise _fail(p, list(pair), "pairs two boundaries (at least one must be a node)")
        if frozenset(pair) in seen:
            raise _fail(p, list(pair), "is declared twice")
        seen.add(frozenset(pair))
        out.append([str(pair[0]), str(pair[1])])
    return out


def _units(units: dict) -> None:
    for k, v in units.items():
        if k not in UNITS:
            raise _fail(f"units.{k}", v, f"is not a known unit key (known: {', '.join(UNITS)})")
        if v != UNITS[k]:
            raise _fail(f"units.{k}", v, f"must be {UNITS[k]!r}: the twin uses fixed units")


def _inputs(section: dict) -> tuple[dict[str, InputSpec], dict]:
    inputs: dict[str, InputSpec] = {}
    spec: dict = {}
    for iname, d in section.items():
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
        spec[iname] = {k: d[k] for k in ("kind", "unit", "default", "min", "max", "from_sensor") if k in d}
    return inputs, spec


def _boundaries(section: dict, inputs: dict) -> tuple[dict[str, BoundarySpec], dict]:
    boundaries: dict[str, BoundarySpec] = {}
    spec: dict = {}
    for bname, p, d in _items(section, "boundaries", {"temperature", "follows", "note"}):
        if ("temperature" in d) == ("follows" in d):
            raise _fail(p, dict(d), "needs exactly one of 'temperature' (a constant or an input) and 'follows'")
        if "follows" in d:
            fol, spec[bname] = _follows(d["follows"], f"{p}.follows", bname, inputs, section)
            boundaries[bname] = BoundarySpec(bname, None, fol)
            continue
        t = d.get("temperature")
        if isinstance(t, str):
            _declared_input(t, inputs, f"{p}.temperature")
            temp: float | str = t
        else:
            temp = _number(d, "temperature", p, lo=-273.15)
        boundaries[bname] = BoundarySpec(bname, temp)
        spec[bname] = {"temperature": temp}
    if not boundaries:
        raise _fail("boundaries", {}, "must name at least one boundary (e.g. ambient)")
    return boundaries, spec


def _follows(raw: Any, path: str, bname: str, inputs: dict, section: dict) -> tuple[FollowSpec, dict]:
    """``follows: {temperature: NAME, gain: 1, offset: 0, tau_s: 0}``: NAME an input or a
    boundary that holds its own temperature; the twin lowers it to an input
    (physics.boundary_follow), which must not clash with a declared one."""
    d = _mapping(raw, path)
    _check_keys(d, {"temperature", "gain", "offset", "tau_s"}, path)
    src = d.get("temperature")
    other = section.get(src) if isinstance(src, str) else None
    if src == bname:
        raise _fail(f"{path}.temperature", src, "is the boundary itself")
    if isinstance(other, Mapping) and "follows" in other:
        raise _fail(f"{path}.temperature", src, "follows another temperature itself (follow its source instead)")
    if not isinstance(src, str) or (src not in inputs and other is None):
        raise _fail(f"{path}.temperature", src, f"is neither a declared input ({', '.join(inputs)}) "
                    f"nor a boundary ({', '.join(section)})")
    if f"{bname}{FOLLOW_SUFFIX}" in inputs:
        raise _fail(path, f"{bname}{FOLLOW_SUFFIX}", "is a declared input; a following boundary needs that name")
    gain = _number(d, "gain", path, default=1.0, lo=-10.0, hi=10.0)
    offset = _number(d, "offset", path, default=0.0, lo=-200.0, hi=200.0)
    tau = _number(d, "tau_s", path, default=0.0, lo=0.0, hi=30 * 86400.0)
    return FollowSpec(src, gain, offset, tau), {"follows": {"temperature": src, "gain": gain, "offset": offset,
                                                            "tau_s": tau}}


def _nodes(section: dict, boundaries: dict) -> tuple[dict[str, NodeSpec], dict]:
    nodes: dict[str, NodeSpec] = {}
    spec: dict = {}
    for nname, d in section.items():
        p = f"nodes.{nname}"
        _check_name(nname, p)
        if nname in boundaries:
            raise _fail(p, nname, "is also a boundary name; names must be unique")
        d = _mapping(d, p)
        _check_keys(d, {"capacity", "note"}, p)
        nodes[nname] = NodeSpec(nname, _number(d, "capacity", p, lo=0.0, lo_open=True))
        spec[nname] = dict(d)
    if not nodes:
        raise _fail("nodes", {}, "must contain at least one node")
    return nodes, spec


def _initial_state(init: Any, boundaries: dict) -> str | dict:
    """``steady``, ``{boundary: NAME}`` or ``{readings: {SENSOR: degC}}`` (the sensors are checked
    once they are parsed: :func:`_check_initial_readings`)."""
    if isinstance(init, Mapping):
        _check_keys(init, {"boundary", "readings"}, "initial_state")
        if len(init) != 1:
            raise _fail("initial_state", dict(init), "must have exactly one of boundary, readings")
        if "readings" in init:
            readings = _mapping(init["readings"], "initial_state.readings")
            return {"readings": {str(k): _number(readings, k, "initial_state.readings", lo=-100.0, hi=300.0)
                                 for k in readings}}
        if init.get("boundary") not in boundaries:
            raise _fail("initial_state.boundary", init.get("boundary"), "is not a boundary")
        return {"boundary": init["boundary"]}
    if init != "steady":
        raise _fail("initial_state", init, "must be 'steady', {boundary: NAME} or {readings: {SENSOR: degC}}")
    return init


def _check_initial_readings(init: str | dict, sensors: dict) -> None:
    """Every sensor of ``initial_state.readings`` exists and sees at least one node."""
    if not isinstance(init, dict) or "readings" not in init:
        return
    if not init["readings"]:
        raise _fail("initial_state.readings", {}, "must name at least one sensor")
    for sid in init["readings"]:
        if sid not in sensors:
            raise _fail("initial_state.readings", sid, "is not a sensor")


def _links(section: dict, nodes: dict, places: set, inputs: dict) -> tuple[dict[str, LinkSpec], dict]:
    links: dict[str, LinkSpec] = {}
    spec: dict = {}
    for lname, p, d in _items(section, "links", {"between", "conductance", "varies_with", "note"}):
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
        vw, vspec = _varies_with(_mapping(d.get("varies_with"), f"{p}.varies_with", required=False),
                                 f"{p}.varies_with", inputs)
        links[lname] = LinkSpec(lname, a, b, g0, vw)
        spec[lname] = {k: v for k, v in d.items() if k != "varies_with"}
        spec[lname]["between"] = [a, b]
        if vspec:
            spec[lname]["varies_with"] = vspec
    return links, spec


def _varies_with(section: dict, path: str, inputs: dict) -> tuple[tuple[tuple[str, float, float], ...], dict]:
    vw = []
    vspec = {}
    for iname, t in section.items():
        q = f"{path}.{iname}"
        _declared_input(iname, inputs, q)
        t = _mapping(t, q)
        _check_keys(t, {"per_unit", "exponent"}, q)
        vw.append((iname, _number(t, "per_unit", q, lo=0.0), _number(t, "exponent", q, default=1.0, lo=0.0)))
        vspec[iname] = dict(t)
    return tuple(vw), vspec


def _sources(section: dict, nodes: dict, inputs: dict) -> tuple[dict[str, SourceSpec], dict]:
    sources: dict[str, SourceSpec] = {}
    spec: dict = {}
    for sname, p, d in _items(section, "sources",
                              {"node", "power", "input", "coefficient", "exponent", "periodic", "note"}):
        node = d.get("node")
        if node not in nodes:
            raise _fail(f"{p}.node", node, "is not a node")
        power = _number(d, "power", p, default=0.0)
        inp = d.get("input")
        if inp is not None:
            _declared_input(inp, inputs, f"{p}.input")
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
        spec[sname] = dict(d)
    return sources, spec


def _sensors(section: dict, places: set) -> tuple[dict[str, SensorSpec], dict]:
    sensors: dict[str, SensorSpec] = {}
    spec: dict = {}
    for sid, p, d in _items(section, "sensors",
                            {"of", "noise_std", "resolution", "lag_s", "bias", "gain", "drift_k_per_h",
                             "position_mm", "note"}):
        pos = _position(d.get("position_mm"), f"{p}.position_mm")
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
                                  _number(d, "gain", p, default=1.0), pos,
                                  _number(d, "drift_k_per_h", p, default=0.0, lo=-MAX_DRIFT_K_PER_H,
                                          hi=MAX_DRIFT_K_PER_H))
        if sensors[sid].gain == 0.0:
            raise _fail(f"{p}.gain", 0.0, "must not be 0 (a reading is read backwards through it)")
        spec[sid] = dict(d)
    return sensors, spec


def _position(pos: Any, path: str) -> tuple[float, float, float] | None:
    if pos is None:
        return None
    if (not isinstance(pos, (list, tuple)) or len(pos) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       for v in pos)):
        raise _fail(path, pos, "must be [x, y, z] in mm (three finite numbers)")
    return tuple(float(v) for v in pos)


def _errors(section: dict, nodes: dict) -> tuple[dict[str, ErrorSpec], dict]:
    errors: dict[str, ErrorSpec] = {}
    spec: dict = {}
    for ename, d in section.items():
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
        for node in terms:
            if node not in nodes:
                raise _fail(f"{p}.terms", node, "is not a node")
            tt.append((node, _number(terms, node, f"{p}.terms")))
        errors[ename] = ErrorSpec(ename, unit, _number(d, "offset", p, default=0.0), tuple(tt))
        spec[ename] = dict(d)
        spec[ename]["unit"] = unit
    return errors, spec
