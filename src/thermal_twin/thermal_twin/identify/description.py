"""The short description a user writes for a machine without a preset (``twin init``): which
sensor sits on which body, which inputs heat (or cool) which bodies, which displacement
channels there are and in which direction, which sensor reads the hall. Validated with a
one-line error naming the field and the value. No rclpy.

```yaml
name: my_mill                      # the twin's name
hall: ambient                      # the sensor that reads the hall (its column ambient_c)
sensors:                           # sensor id (column <id>_c) -> the body it sits on
  spindle_housing: head
  motor_internal: {body: motor, resolution: 1.0}
  coolant_delta: {body: coolant, minus: chiller}   # a difference: body minus a boundary
boundaries:                        # constant degC, an input name, or a sensor's reading,
  chiller: 22.0                    # optionally with the bodies it touches all the time
  fluid: fluid_temp_degc
  jacket: {sensor: coolant_return, bodies: [motor]}
inputs:                            # machine inputs of the recording
  spindle_rpm: {heats: [motor, head], exponent: 1.0, moves: true}   # moves: a speed that stirs the air
  fluid_on: {cools: [table], boundary: fluid}     # a switch that links bodies to a boundary
  fluid_temp_degc: {}
displacements:                     # channel -> direction (x y z radial: um; a b c tilt: um/m)
  E_Z0T: {direction: z}
contacts: [[motor, head]]          # optional: which bodies touch (default: every pair)
hidden: 2                          # optional: most hidden bodies to try (0-3, default 2)
loop_length_m: 2.0                 # optional: the structural loop tool-workpiece (m), bounds the gains
alpha_per_k: 11.5e-6               # optional: its expansion coefficient (default steel / cast iron)
```
"""
from __future__ import annotations

import math
import pathlib
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

import yaml

LINEAR_DIRECTIONS = ("x", "y", "z", "radial")
ANGULAR_DIRECTIONS = ("a", "b", "c")
MAX_HIDDEN = 3
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_TOP_KEYS = ("name", "description", "hall", "sensors", "boundaries", "inputs", "displacements", "contacts",
             "hidden", "loop_length_m", "alpha_per_k")
STEEL_ALPHA = 11.5e-6     # 1/K, steel and cast iron (10-12e-6)


class DescriptionError(ValueError):
    """The description cannot be used; the message names the field and the value."""


@dataclass
class SensorPlace:
    body: str
    minus: str = ""          # a boundary subtracted (a delta sensor), "" for none
    resolution: float = 0.0


@dataclass
class InputUse:
    heats: list[str] = field(default_factory=list)
    exponent: float = 1.0
    cools: list[str] = field(default_factory=list)
    boundary: str = ""
    unit: str = ""
    moves: bool = False      # a speed: the hidden bodies' exchange with the hall grows with it


@dataclass
class Description:
    name: str
    hall: str
    sensors: dict[str, SensorPlace]
    boundaries: dict[str, float | str]     # constant, an input name, or "sensor:<id>"
    cooled: dict[str, list[str]]            # boundary -> bodies it touches all the time
    inputs: dict[str, InputUse]
    displacements: dict[str, str]           # channel -> direction
    contacts: list[tuple[str, str]] | None
    hidden: int
    text: str = ""
    loop_length_m: float = 0.0              # 0: not given (no physical bound on the gains)
    alpha_per_k: float = STEEL_ALPHA

    def gain_bound(self) -> float:
        """The largest thermo-elastic gain a body can have, um/K (um/m per K for a tilt): the whole
        loop at the body's temperature expands by alpha x length; a tilt is taken over a base of 1 m.
        0 when the description gives no loop length."""
        return self.alpha_per_k * self.loop_length_m * 1e6

    @property
    def bodies(self) -> list[str]:
        """Every body a sensor sits on, in the order first named."""
        return list(dict.fromkeys(p.body for p in self.sensors.values() if p.body))

    def unit(self, channel: str) -> str:
        return "um/m" if self.displacements[channel] in ANGULAR_DIRECTIONS else "um"

    def pairs(self) -> list[tuple[str, str]]:
        """The body pairs that exchange heat: the contacts, or every pair."""
        if self.contacts is not None:
            return list(self.contacts)
        b = self.bodies
        return [(b[i], b[j]) for i in range(len(b)) for j in range(i + 1, len(b))]


def _name(v: Any, where: str) -> str:
    if not isinstance(v, str) or not _NAME.match(v):
        raise DescriptionError(f"{where}: {v!r} must be a name (a letter, then letters, digits or _)")
    return v


def _mapping(v: Any, where: str) -> Mapping:
    if v is None:
        return {}
    if not isinstance(v, Mapping):
        raise DescriptionError(f"{where}: {v!r} must be a mapping")
    return v


def _number(v: Any, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise DescriptionError(f"{where}: {v!r} must be a number within [{lo:g}, {hi:g}]")
    return float(v)


def _names(v: Any, where: str) -> list[str]:
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list):
        raise DescriptionError(f"{where}: {v!r} must be a list of names")
    return [_name(x, f"{where}[{i}]") for i, x in enumerate(v)]


def _sensors(raw: Mapping) -> dict[str, SensorPlace]:
    out = {}
    for sid, v in raw.items():
        where = f"sensors.{sid}"
        _name(sid, "sensors")
        if isinstance(v, str) or v is None:
            out[sid] = SensorPlace(_name(v, where) if v else "")
            continue
        v = _mapping(v, where)
        bad = [k for k in v if k not in ("body", "minus", "resolution")]
        if bad:
            raise DescriptionError(f"{where}.{bad[0]}: {v[bad[0]]!r} is not a known key (body, minus, resolution)")
        out[sid] = SensorPlace(_name(v.get("body"), f"{where}.body"),
                               _name(v["minus"], f"{where}.minus") if "minus" in v else "",
                               _number(v.get("resolution", 0.0), f"{where}.resolution", 0.0, 10.0))
    return out


def _inputs(raw: Mapping) -> dict[str, InputUse]:
    out = {}
    for name, v in raw.items():
        where = f"inputs.{name}"
        _name(name, "inputs")
        v = _mapping(v, where)
        bad = [k for k in v if k not in ("heats", "exponent", "cools", "boundary", "unit", "moves")]
        if bad:
            raise DescriptionError(f"{where}.{bad[0]}: {v[bad[0]]!r} is not a known key "
                                   "(heats, exponent, cools, boundary, unit, moves)")
        if not isinstance(v.get("moves", False), bool):
            raise DescriptionError(f"{where}.moves: {v['moves']!r} must be true or false")
        use = InputUse(_names(v.get("heats", []), f"{where}.heats"),
                       _number(v.get("exponent", 1.0), f"{where}.exponent", 0.25, 4.0),
                       _names(v.get("cools", []), f"{where}.cools"),
                       _name(v["boundary"], f"{where}.boundary") if "boundary" in v else "",
                       str(v.get("unit", "")), bool(v.get("moves", False)))
        if use.cools and not use.boundary:
            raise DescriptionError(f"{where}.boundary: missing; 'cools' needs the boundary the bodies are linked to")
        out[name] = use
    return out


def _check_names(d: Description) -> None:
    bodies = set(d.bodies)
    if not bodies:
        raise DescriptionError(f"sensors: {list(d.sensors)!r} puts no sensor on a body; name at least one body")
    if d.hall not in d.sensors:
        raise DescriptionError(f"hall: {d.hall!r} is not one of the sensors {sorted(d.sensors)}")
    if d.sensors[d.hall].body:
        raise DescriptionError(f"sensors.{d.hall}: the hall sensor sits on no body; got {d.sensors[d.hall].body!r}")
    clash = bodies & (set(d.boundaries) | {"ambient"})
    if clash:
        raise DescriptionError(f"boundaries: {sorted(clash)[0]!r} is also a body")
    for sid, p in d.sensors.items():
        if p.minus and p.minus not in d.boundaries:
            raise DescriptionError(f"sensors.{sid}.minus: {p.minus!r} is not one of the boundaries "
                                   f"{sorted(d.boundaries)}")
    for b, t in d.boundaries.items():
        if isinstance(t, str) and t.startswith("sensor:"):
            sid = t.split(":", 1)[1]
            if sid not in d.sensors or d.sensors[sid].body:
                raise DescriptionError(f"boundaries.{b}.sensor: {sid!r} is not a sensor on no body "
                                       f"{sorted(k for k, p in d.sensors.items() if not p.body)}")
        elif isinstance(t, str) and t not in d.inputs:
            raise DescriptionError(f"boundaries.{b}: {t!r} is no number and not one of the inputs {sorted(d.inputs)}")
    for name, use in d.inputs.items():
        for i, body in enumerate(use.heats):
            if body not in bodies:
                raise DescriptionError(f"inputs.{name}.heats[{i}]: {body!r} is not a body a sensor sits on "
                                       f"{sorted(bodies)}")
        for i, body in enumerate(use.cools):
            if body not in bodies:
                raise DescriptionError(f"inputs.{name}.cools[{i}]: {body!r} is not a body {sorted(bodies)}")
        if use.boundary and use.boundary not in d.boundaries:
            raise DescriptionError(f"inputs.{name}.boundary: {use.boundary!r} is not one of the boundaries "
                                   f"{sorted(d.boundaries)}")
    for b, touched in d.cooled.items():
        for i, body in enumerate(touched):
            if body not in bodies:
                raise DescriptionError(f"boundaries.{b}.bodies[{i}]: {body!r} is not a body {sorted(bodies)}")
    for i, (a, b) in enumerate(d.contacts or []):
        for x in (a, b):
            if x not in bodies:
                raise DescriptionError(f"contacts[{i}]: {x!r} is not a body {sorted(bodies)}")


def parse_description(raw: Any, text: str = "") -> Description:
    """A validated :class:`Description` from the parsed YAML (module docstring)."""
    raw = _mapping(raw, "description")
    bad = [k for k in raw if k not in _TOP_KEYS]
    if bad:
        raise DescriptionError(f"{bad[0]}: {raw[bad[0]]!r} is not a known key ({', '.join(_TOP_KEYS)})")
    for key in ("name", "hall", "sensors", "displacements"):
        if key not in raw:
            raise DescriptionError(f"{key}: missing")
    bounds, cooled = {}, {}
    for b, t in _mapping(raw.get("boundaries"), "boundaries").items():
        _name(b, "boundaries")
        if isinstance(t, Mapping):
            bad = [k for k in t if k not in ("temperature", "sensor", "bodies")]
            if bad or ("temperature" in t) == ("sensor" in t):
                raise DescriptionError(f"boundaries.{b}: {dict(t)!r} needs exactly one of temperature, sensor "
                                       "(and optionally bodies)")
            cooled[b] = _names(t.get("bodies", []), f"boundaries.{b}.bodies")
            t = f"sensor:{_name(t['sensor'], f'boundaries.{b}.sensor')}" if "sensor" in t else t["temperature"]
        bounds[b] = _name(t, f"boundaries.{b}") if isinstance(t, str) and not t.startswith("sensor:") else (
            t if isinstance(t, str) else _number(t, f"boundaries.{b}", -50, 200))
    disp = {}
    for ch, v in _mapping(raw["displacements"], "displacements").items():
        v = {"direction": v} if isinstance(v, str) else _mapping(v, f"displacements.{ch}")
        direction = str(v.get("direction", "")).lower()
        if direction not in LINEAR_DIRECTIONS + ANGULAR_DIRECTIONS:
            raise DescriptionError(f"displacements.{ch}.direction: {v.get('direction')!r} must be one of "
                                   f"{', '.join(LINEAR_DIRECTIONS + ANGULAR_DIRECTIONS)}")
        disp[_name(ch, "displacements")] = direction
    if not disp:
        raise DescriptionError("displacements: {} names no channel")
    contacts = None
    if raw.get("contacts") is not None:
        if not isinstance(raw["contacts"], list):
            raise DescriptionError(f"contacts: {raw['contacts']!r} must be a list of [body, body] pairs")
        contacts = []
        for i, pair in enumerate(raw["contacts"]):
            if not isinstance(pair, list) or len(pair) != 2 or pair[0] == pair[1]:
                raise DescriptionError(f"contacts[{i}]: {pair!r} must be a pair of two different bodies")
            contacts.append((_name(pair[0], f"contacts[{i}]"), _name(pair[1], f"contacts[{i}]")))
    d = Description(_name(raw["name"], "name"), _name(raw["hall"], "hall"),
                    _sensors(_mapping(raw["sensors"], "sensors")), bounds, cooled,
                    _inputs(_mapping(raw.get("inputs"), "inputs")), disp, contacts,
                    int(_number(raw.get("hidden", 2), "hidden", 0, MAX_HIDDEN)), text,
                    _number(raw.get("loop_length_m", 0.0), "loop_length_m", 0.0, 100.0),
                    _number(raw.get("alpha_per_k", STEEL_ALPHA), "alpha_per_k", 1e-7, 1e-4))
    _check_names(d)
    return d


def load_description(source: str | pathlib.Path | Mapping) -> Description:
    """A description from a YAML file, YAML text or a mapping."""
    if isinstance(source, Mapping):
        return parse_description(source)
    text = str(source)
    path = pathlib.Path(text)
    if "\n" not in text and path.suffix.lower() in (".yaml", ".yml"):
        if not path.is_file():
            raise DescriptionError(f"--description {text!r}: no such file")
        text = path.read_text()
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DescriptionError(f"--description: not YAML ({str(exc).splitlines()[0]})") from None
    return parse_description(raw, text)
