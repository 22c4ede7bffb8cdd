"""The starting structure of a twin made from a description and a recording: every body a
sensor sits on is a node, plus ``hidden`` hidden bodies; every node exchanges heat with the hall
and with the bodies it touches (a hidden body with the bodies an input heats and the hidden bodies
before it: it stands for the unsensed structure those heat and the hall drives, heat that flows on
deeper into the machine; with a speed that ``moves``, its exchange with the
hall grows with the speed^0.8, as forced convection of a turning part does); every heating input has a
source on the bodies it heats and on each hidden body; every displacement channel has a
thermo-elastic term on every node but the fluids (a body whose sensor reads a difference against a
boundary is a coolant circuit: it carries heat away and deforms nothing). Start values are orders of magnitude (a body of 1e5 J/K with
a time constant of hours, a source that warms its body by the range its sensor shows); the fit
(:mod:`thermal_twin.identify.identification`) moves them. The result is a machine description in the
project's schema (thermal_twin.machine.schema). No rclpy.
"""
from __future__ import annotations

import numpy as np

from thermal_comp_common.recording_csv import Recording

from thermal_twin.identify.description import Description, DescriptionError

HALL_BOUNDARY = "ambient"
HALL_INPUT = "ambient_degc"
BODY_CAPACITY = 1.0e5          # J/K: order of a 200 kg steel body
HALL_CONDUCTANCE = 10.0        # W/K: time constant C/G of about 3 h
CONTACT_CONDUCTANCE = 5.0      # W/K between bodies that touch
FLOW_CONDUCTANCE = 50.0        # W/K from a body to the boundary its delta sensor is read against
SWITCH_CONDUCTANCE = 20.0      # W/K per unit of a switch that links bodies to a boundary
CONVECTION_EXPONENT = 0.8      # forced convection: h grows with the speed^0.8 (turbulent flow over a body)
HIDDEN_CAPACITY = 3.0e5        # J/K of the first hidden body; the next ones 3 x slower each


def hidden_name(i: int) -> str:
    return f"hidden_{i + 1}"


def _column(rec: Recording, name: str, where: str) -> np.ndarray:
    if name not in rec.columns:
        raise DescriptionError(f"{where}: column {name!r} is not in the recording {rec.source or ''} "
                               f"(columns: {', '.join(sorted(rec.columns))})")
    x = np.asarray(rec.columns[name], float)
    if np.isfinite(x).sum() < 2:
        raise DescriptionError(f"{where}: column {name!r} of the recording holds no value")
    return x


def _span(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.percentile(x, 95) - np.percentile(x, 5))


def _inputs(d: Description, rec: Recording) -> dict:
    hall = _column(rec, f"{d.hall}_c", f"hall {d.hall!r}")
    out = {}
    temp_inputs = {t for t in d.boundaries.values() if isinstance(t, str)}
    for name, use in d.inputs.items():
        x = _column(rec, name, f"inputs.{name}")
        x = x[np.isfinite(x)]
        lo, hi = float(min(0.0, x.min())), float(max(x.max(), x.min() + 1.0))
        default = float(np.median(x)) if name in temp_inputs else float(np.clip(0.0, lo, hi))
        unit = use.unit or ("degC" if name in temp_inputs else "")
        out[name] = {"kind": "machine", "unit": unit, "default": default, "min": lo - abs(lo), "max": 2.0 * hi}
    for b, t in d.boundaries.items():
        if isinstance(t, str) and t.startswith("sensor:"):
            sid = t.split(":", 1)[1]
            x = _column(rec, f"{sid}_c", f"boundaries.{b}.sensor")
            out[f"{b}_degc"] = {"kind": "environment", "unit": "degC", "default": float(np.nanmedian(x)),
                                "min": -10.0, "max": 60.0, "from_sensor": sid}
    h = hall[np.isfinite(hall)]
    out[HALL_INPUT] = {"kind": "environment", "unit": "degC", "default": float(np.clip(h[0], -10, 50)),
                       "min": -10.0, "max": 60.0, "from_sensor": d.hall}
    return out


def _input_max(rec: Recording, name: str) -> float:
    x = np.abs(np.asarray(rec.columns[name], float))
    x = x[np.isfinite(x)]
    m = float(np.percentile(x, 99)) if x.size else 0.0
    return m if m > 0 else 1.0


def _rise(d: Description, rec: Recording, body: str) -> float:
    """How far a body's sensors range (K, at least 1): the scale of its heat input."""
    spans = [_span(_column(rec, f"{sid}_c", f"sensors.{sid}")) for sid, p in d.sensors.items() if p.body == body]
    return max([1.0] + spans)


def _links(d: Description, hidden: int, u_max: dict[str, float]) -> dict:
    links = {}
    bodies = d.bodies
    heated = list(dict.fromkeys(b for use in d.inputs.values() for b in use.heats))
    for b in bodies:
        links[f"{b}_hall"] = {"between": [b, HALL_BOUNDARY], "conductance": HALL_CONDUCTANCE}
    for a, b in d.pairs():
        links[f"{a}_{b}"] = {"between": [a, b], "conductance": CONTACT_CONDUCTANCE}
    for sid, p in d.sensors.items():
        if p.minus and f"{p.body}_{p.minus}" not in links:
            links[f"{p.body}_{p.minus}"] = {"between": [p.body, p.minus], "conductance": FLOW_CONDUCTANCE}
    for bound, touched in d.cooled.items():
        for b in touched:
            links[f"{b}_{bound}"] = {"between": [b, bound], "conductance": FLOW_CONDUCTANCE}
    for name, use in d.inputs.items():
        for b in use.cools:
            key = f"{b}_{use.boundary}_{name}"
            links[key] = {"between": [b, use.boundary], "conductance": 0.0,
                          "varies_with": {name: {"per_unit": SWITCH_CONDUCTANCE}}}
    for i in range(hidden):
        h = hidden_name(i)
        links[f"{h}_hall"] = {"between": [h, HALL_BOUNDARY], "conductance": HALL_CONDUCTANCE}
        moving = {n: {"per_unit": HALL_CONDUCTANCE / u_max[n] ** CONVECTION_EXPONENT, "exponent": CONVECTION_EXPONENT}
                  for n, use in d.inputs.items() if use.moves}
        if moving:
            links[f"{h}_hall"]["varies_with"] = moving
        for b in heated + [hidden_name(j) for j in range(i)]:
            links[f"{h}_{b}"] = {"between": [h, b], "conductance": CONTACT_CONDUCTANCE / 2.0}
    return links


def _sources(d: Description, rec: Recording, hidden: int) -> dict:
    sources = {}
    for name, use in d.inputs.items():
        if not use.heats:
            continue
        u_max = _input_max(rec, name)
        watts = []
        for b in use.heats:
            w = (HALL_CONDUCTANCE + CONTACT_CONDUCTANCE) * _rise(d, rec, b)
            watts.append(w)
            sources[f"{name}_{b}"] = {"node": b, "input": name, "coefficient": w / u_max ** use.exponent,
                                      "exponent": use.exponent}
        for i in range(hidden):
            sources[f"{name}_{hidden_name(i)}"] = {"node": hidden_name(i), "input": name,
                                                   "coefficient": 0.5 * max(watts) / u_max ** use.exponent,
                                                   "exponent": use.exponent}
    return sources


def starting_spec(d: Description, rec: Recording, hidden: int = 0) -> dict:
    """The machine description of the starting structure with ``hidden`` hidden bodies."""
    nodes = {b: {"capacity": BODY_CAPACITY} for b in d.bodies}
    for i in range(hidden):
        nodes[hidden_name(i)] = {"capacity": HIDDEN_CAPACITY * 3.0 ** i,
                                 "note": "hidden body: no sensor on it, added because held-out data needed it"}
    boundaries = {HALL_BOUNDARY: {"temperature": HALL_INPUT}}
    boundaries |= {b: {"temperature": f"{b}_degc" if isinstance(t, str) and t.startswith("sensor:") else t}
                   for b, t in d.boundaries.items()}
    sensors = {d.hall: {"of": HALL_BOUNDARY}}
    sensors |= {t.split(":", 1)[1]: {"of": b} for b, t in d.boundaries.items()
                if isinstance(t, str) and t.startswith("sensor:")}
    for sid, p in d.sensors.items():
        if sid in sensors:
            continue
        if not p.body:
            raise DescriptionError(f"sensors.{sid}: sits on no body and reads no boundary (hall or a boundary's sensor)")
        s = {"of": {p.body: 1.0, p.minus: -1.0} if p.minus else p.body}
        if p.resolution:
            s["resolution"] = p.resolution
        _column(rec, f"{sid}_c", f"sensors.{sid}")
        sensors[sid] = s
    fluids = {p.body for p in d.sensors.values() if p.minus}
    names = [n for n in nodes if n not in fluids]
    errors = {}
    for ch in d.displacements:
        _column(rec, ch, f"displacements.{ch}")
        errors[ch] = {"unit": d.unit(ch), "terms": {n: 0.0 for n in names},
                      "note": f"direction {d.displacements[ch]}"}
    spec = {"schema_version": 1, "name": d.name,
            "description": f"lumped twin made by twin init from {rec.source or 'a recording'}",
            "units": {"temperature": "degC", "time": "s", "capacity": "J/K", "conductance": "W/K", "power": "W",
                      "error_linear": "um", "error_angular": "um/m"},
            "initial_state": "steady", "inputs": _inputs(d, rec), "boundaries": boundaries, "nodes": nodes,
            "links": _links(d, hidden, {n: _input_max(rec, n) for n in d.inputs}), "sources": _sources(d, rec, hidden), "sensors": sensors, "errors": errors}
    if d.contacts is not None:
        spec["contacts"] = [list(p) for p in d.contacts]
    return spec
