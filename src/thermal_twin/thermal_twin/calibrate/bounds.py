"""Which parameters of a twin a calibration may move, and how far.

Every numeric physics parameter of a machine description has a *kind* with a default
range (below); a machine YAML's optional ``calibration`` section (or a separate bounds
file given to ``thermal-comp calibrate --bounds``) overrides a kind or one parameter::

    calibration:
      kinds: {capacity: fixed, bias: {absolute: 5.0}}     # override a kind's default
      parameters:                                         # override one parameter
        links.jacket_flow.conductance: {factor: 1.5}
        sensors.t5.bias: {bounds: [-10, 10]}
        nodes.base.capacity: fixed

``factor: f`` lets a positive value move within [v0/f, v0*f] (fitted on a log scale);
``tolerance: r`` and ``absolute: a`` let a value move by +-max(r*|v0|, a) (additive);
``bounds: [lo, hi]`` sets the range directly; ``fixed`` keeps the value.
"""
from __future__ import annotations

import copy
import difflib
import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

# kind -> (default rule, what it is); rules as in the module docstring. The defaults are the
# tolerances a builder would state for a twin built from drawings and data sheets; the
# calibration also pulls every parameter toward its nominal value with a prior whose 95 %
# range is the tolerance (see calibration.py), so that a calibration does not absorb physics
# the twin lacks by moving everything to its limits.
DEFAULT_KINDS: dict[str, dict] = {
    "conductance": {"tolerance": 0.3},       # links.<l>.conductance [W/K]
    "convection": {"tolerance": 0.3},        # links.<l>.varies_with.<input>.per_unit
    "capacity": {"tolerance": 0.3},          # nodes.<n>.capacity [J/K]
    "source": {"tolerance": 0.3},            # sources.<s>.coefficient (or .power without input) [W]
    "gain": {"tolerance": 0.3, "absolute": 0.1},   # errors.<ch>.terms.<node> [um/K]
    "bias": {"absolute": 0.5},               # sensors.<id>.bias [K]
    "boundary": {"absolute": 1.0},           # boundaries.<b>.temperature (constants only) [degC]
}
UNITS = {"conductance": "W/K", "convection": "W/K per unit^n", "capacity": "J/K", "source": "W",
         "gain": "um/K", "bias": "K", "boundary": "degC"}


class CalibrationSpecError(ValueError):
    """A calibration section or bounds file is invalid; the message names the key and value."""


@dataclass(frozen=True)
class Param:
    """One free parameter: ``path`` into the machine description, start value and range.
    ``log``: fitted as theta = ln(v / v0) (positive kinds with a factor), else theta = v - v0."""

    name: str                 # dotted path, e.g. links.motor_shaft.conductance
    kind: str
    path: tuple[str, ...]
    value0: float
    lo: float
    hi: float
    log: bool
    unit_text: str = ""       # the unit when the kind's is not the whole story (a coefficient per input^n)

    @property
    def theta_bounds(self) -> tuple[float, float]:
        if self.log:
            return math.log(self.lo / self.value0), math.log(self.hi / self.value0)
        return self.lo - self.value0, self.hi - self.value0

    def value(self, theta: float) -> float:
        return self.value0 * math.exp(theta) if self.log else self.value0 + theta

    def theta(self, value: float) -> float:
        """The inverse of :meth:`value`."""
        return math.log(value / self.value0) if self.log else value - self.value0

    @property
    def unit(self) -> str:
        return self.unit_text or UNITS[self.kind]


def all_parameters(spec: Mapping) -> list[tuple[str, str, tuple[str, ...], float]]:
    """(name, kind, path, value) of every calibratable number in a machine description."""
    out = []
    for l, d in spec.get("links", {}).items():
        out.append((f"links.{l}.conductance", "conductance", ("links", l, "conductance"), float(d["conductance"])))
        for inp, v in (d.get("varies_with") or {}).items():
            out.append((f"links.{l}.varies_with.{inp}.per_unit", "convection",
                        ("links", l, "varies_with", inp, "per_unit"), float(v["per_unit"])))
    for n, d in spec.get("nodes", {}).items():
        out.append((f"nodes.{n}.capacity", "capacity", ("nodes", n, "capacity"), float(d["capacity"])))
    for s, d in spec.get("sources", {}).items():
        key = "coefficient" if d.get("input") else "power"
        out.append((f"sources.{s}.{key}", "source", ("sources", s, key), float(d.get(key, 0.0))))
    for e, d in spec.get("errors", {}).items():
        for node, g in (d.get("terms") or {}).items():
            out.append((f"errors.{e}.terms.{node}", "gain", ("errors", e, "terms", node), float(g)))
    for sid, d in spec.get("sensors", {}).items():
        out.append((f"sensors.{sid}.bias", "bias", ("sensors", sid, "bias"), float(d.get("bias", 0.0))))
    for b, d in spec.get("boundaries", {}).items():
        if "temperature" in d and not isinstance(d["temperature"], str):   # not a following boundary
            out.append((f"boundaries.{b}.temperature", "boundary", ("boundaries", b, "temperature"),
                        float(d["temperature"])))
    return out


def _rule(value: Any, where: str) -> dict | None:
    """A rule mapping, or None for ``fixed``."""
    if value == "fixed" or value is False:
        return None
    if not isinstance(value, Mapping):
        raise CalibrationSpecError(f"{where}: {value!r} must be 'fixed' or a mapping with factor, "
                                   f"tolerance/absolute or bounds")
    bad = [k for k in value if k not in ("factor", "tolerance", "absolute", "bounds")]
    if bad:
        raise CalibrationSpecError(f"{where}.{bad[0]}: {value[bad[0]]!r} is not a known key "
                                   f"(allowed: absolute, bounds, factor, tolerance)")
    for k in ("factor", "tolerance", "absolute"):
        if k in value:
            v = value[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 \
                    or (k == "factor" and v <= 1):
                raise CalibrationSpecError(f"{where}.{k}: {v!r} must be a finite number "
                                           f"{'> 1' if k == 'factor' else '>= 0'}")
    if "bounds" in value:
        b = value["bounds"]
        if (not isinstance(b, (list, tuple)) or len(b) != 2
                or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in b) or b[0] >= b[1]):
            raise CalibrationSpecError(f"{where}.bounds: {b!r} must be [lo, hi] with lo < hi")
    return dict(value)


def _apply(name: str, kind: str, path: tuple, v0: float, rule: dict) -> Param | None:
    if "bounds" in rule:
        lo, hi = float(rule["bounds"][0]), float(rule["bounds"][1])
        if not lo <= v0 <= hi:
            raise CalibrationSpecError(f"calibration.parameters.{name}.bounds: [{lo:g}, {hi:g}] "
                                       f"does not contain the twin's value {v0:g}")
        return Param(name, kind, path, v0, lo, hi, log=False)
    if "factor" in rule:
        if v0 <= 0:
            return None            # a zero conductance or source cannot be scaled: left fixed
        f = float(rule["factor"])
        return Param(name, kind, path, v0, v0 / f, v0 * f, log=True)
    half = max(float(rule.get("tolerance", 0.0)) * abs(v0), float(rule.get("absolute", 0.0)))
    if half <= 0:
        return None
    return Param(name, kind, path, v0, v0 - half, v0 + half, log=False)


def free_parameters(spec: Mapping, section: Mapping | None = None) -> list[Param]:
    """The parameters a calibration of ``spec`` may move, with their ranges: the kinds'
    defaults, overridden by ``section`` (the machine's ``calibration`` section or a bounds
    file with the same keys)."""
    section = dict(section or {})
    bad = [k for k in section if k not in ("kinds", "parameters")]
    if bad:
        raise CalibrationSpecError(f"calibration.{bad[0]}: {section[bad[0]]!r} is not a known key "
                                   f"(allowed: kinds, parameters)")
    kinds = {k: dict(v) for k, v in DEFAULT_KINDS.items()}
    for k, v in (section.get("kinds") or {}).items():
        if k not in DEFAULT_KINDS:
            raise CalibrationSpecError(f"calibration.kinds.{k}: {v!r}: {k!r} is not a kind "
                                       f"(kinds: {', '.join(DEFAULT_KINDS)})")
        kinds[k] = _rule(v, f"calibration.kinds.{k}")
    per = dict(section.get("parameters") or {})
    known = {p[0] for p in all_parameters(spec)}
    unknown = [k for k in per if k not in known]
    if unknown:
        close = difflib.get_close_matches(unknown[0], sorted(known), n=1)
        raise CalibrationSpecError(f"calibration.parameters.{unknown[0]}: no such parameter in the twin"
                                   + (f" (closest: {close[0]})" if close else ""))
    out = []
    for name, kind, path, v0 in all_parameters(spec):
        rule = _rule(per[name], f"calibration.parameters.{name}") if name in per else kinds[kind]
        if rule is None:
            continue
        p = _apply(name, kind, path, v0, rule)
        if p is not None:
            out.append(replace(p, unit_text=_unit_of(spec, path)))
    return out


def _unit_of(spec: Mapping, path: tuple) -> str:
    """A source coefficient is W per (input unit)^exponent and a convection W/K per
    (input unit)^exponent, not W or W/K: the unit printed with its input (empty: the kind's)."""
    if path[0] == "sources" and path[-1] == "coefficient":
        d = spec["sources"][path[1]]
        unit = (spec.get("inputs", {}).get(d["input"]) or {}).get("unit", d["input"])
        return f"W per ({unit})^{float(d.get('exponent', 1.0)):g}"
    if path[0] == "links" and path[2] == "varies_with":
        v = spec["links"][path[1]]["varies_with"][path[3]]
        unit = (spec.get("inputs", {}).get(path[3]) or {}).get("unit", path[3])
        return f"W/K per ({unit})^{float(v.get('exponent', 1.0)):g}"
    return ""


def set_values(spec: dict, params: list[Param], values) -> dict:
    """Write ``values`` (one per parameter) into ``spec`` in place; returns ``spec``."""
    for p, v in zip(params, values):
        d = spec
        for k in p.path[:-1]:
            d = d[k]
        d[p.path[-1]] = float(v)
    return spec


def patch_machine(machine, params: list[Param], values):
    """A copy of the validated ``machine`` with ``values`` (one per parameter) in its
    records, without re-validating the description: the calibration's inner loop (a
    parameter within its range cannot make a valid machine invalid, except a conductance
    or capacity driven to zero, which the ranges exclude). ``machine.spec`` is not updated:
    :func:`set_values` writes the description."""
    m = copy.copy(machine)
    tables = {k: dict(getattr(machine, k)) for k in ("links", "nodes", "sources", "errors", "sensors",
                                                      "boundaries")}
    for p, v in zip(params, values):
        v = float(v)
        kind, key = p.path[0], p.path[1]
        rec = tables[kind][key]
        if p.kind == "convection":
            vw = tuple((i, v if i == p.path[3] else pu, e) for i, pu, e in rec.varies_with)
            rec = replace(rec, varies_with=vw)
        elif p.kind == "gain":
            rec = replace(rec, terms=tuple((n, v if n == p.path[3] else g) for n, g in rec.terms))
        else:
            rec = replace(rec, **{p.path[-1]: v})
        tables[kind][key] = rec
    for k, d in tables.items():
        setattr(m, k, d)
    return m


def check_section(section: Mapping, spec: Mapping) -> dict:
    """A machine's ``calibration`` section, checked against its own description (the
    machine validation calls this); raises :class:`CalibrationSpecError`, a ValueError
    naming the key and the value."""
    free_parameters(spec, section)
    return {k: dict(v) if isinstance(v, Mapping) else v for k, v in section.items()}
