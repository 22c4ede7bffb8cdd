"""The effect library of the mismatch finder: physics a twin may have left out.

Every effect is a parametric edit of the twin's machine description (the YAML schema of
:mod:`thermal_twin.machine.schema`), so an adopted hypothesis is simply the augmented YAML.
Vocabulary (``EFFECTS``):

==========================  =========================================================  ==========================
effect                      edit of the machine description                            fitted parameters
==========================  =========================================================  ==========================
heat_source                 new ``sources`` entry on a node driven by an input          P_max [W] at the input's
                            (P = P_max (|u|/u_max)^n)                                   maximum, n [-] (speed inputs)
ambient_coupling            new/changed ``links`` node <-> ambient boundary             dG [W/K]
conduction                  new ``links`` entry between two nodes that have none, or    G [W/K]
                            a node and a boundary other than the hall air (a contact,
                            a cooling jacket the twin lacks); only declared ``contacts``
                            pairs if the description declares any
time_lag                    sensor: ``lag_s``; error channel: its nodes seen through    tau [s]
                            a small lag node (capacity 1e-3 C, G = C/tau)
speed_dependent_convection  ``varies_with`` on the node's ambient link,                 dG_max [W/K] at max speed
                            G += dG_max (|v|/v_max)^0.8 (turbulent Nusselt ~ Re^0.8)
coolant                     link node <-> coolant boundary switched by the coolant      G_on [W/K], T_coolant [degC]
                            input (new boundary at a fitted temperature if none)        (only if a new boundary)
door_event                  ``varies_with`` door input on the node's ambient link        dG_open [W/K]
sensor_bias                 ``sensors.<id>.bias`` (more than half the resolution)       bias [K]
elastic_gain                change of ``errors.<ch>.terms.<node>`` (a node touching     d_gain [um/K]
                            the channel's nodes gets a term from 0, if ``contacts``
                            are declared)
periodic_load               new source with a 24 h sinusoid (sun, hall heating)         amplitude [W], phase [s]
none                        no edit                                                     -
==========================  =========================================================  ==========================

Each candidate knows its bounds for fitting (generous, so that a wrong fit shows up as
such) and a plausibility check against physical ranges (sign, time constants, energy).
Pure Python; no simulation here (see :mod:`thermal_twin.diagnose.fit`).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

EFFECTS = ("heat_source", "ambient_coupling", "conduction", "time_lag", "speed_dependent_convection", "coolant",
           "door_event", "sensor_bias", "elastic_gain", "periodic_load", "none")

#: physically plausible ranges used by the plausibility checks
TAU_RANGE_S = (30.0, 8 * 3600.0)          # sensor/structure lag time constants
CONVECTION_EXPONENT = 0.8
DAY_S = 86400.0
MAX_SOURCE_W = 5000.0                      # an unmodelled source larger than this is not missing physics
MAX_CONDUCTANCE_W_K = 200.0
MAX_ELASTIC_UM_K = 60.0
MAX_BIAS_K = 5.0


@dataclass(frozen=True)
class ParamSpec:
    name: str
    unit: str
    lo: float           # fitting bound
    hi: float
    x0: float           # start value (also the screening value of the amplitude parameter)


@dataclass
class Candidate:
    """One hypothesis before fitting: an effect on a target, maybe driven by an input."""

    effect: str
    target: str                     # node, sensor id or error channel
    driver: str | None
    params: list[ParamSpec]
    apply_fn: Callable[[dict, np.ndarray], dict] = field(repr=False)
    check_fn: Callable[[np.ndarray], str | None] = field(repr=False)
    affects: list[str] = field(default_factory=list)   # channels it can change directly ([] = any)

    @property
    def key(self) -> str:
        return f"{self.effect}:{self.target}:{self.driver or '-'}"

    def apply(self, spec: dict, values) -> dict:
        """A new machine description (deep copy of ``spec``) with the effect applied."""
        return self.apply_fn(copy.deepcopy(spec), np.asarray(values, dtype=float))

    def implausible(self, values) -> str | None:
        """None if the fitted values are physically plausible, else the reason."""
        return self.check_fn(np.asarray(values, dtype=float))

    def param_dict(self, values) -> dict:
        return {p.name: {"value": float(v), "unit": p.unit} for p, v in zip(self.params, values)}


@dataclass
class DriverInfo:
    """What the recording says about an input: its maximum magnitude and kind."""

    name: str
    max_abs: float
    kind: str            # "speed", "switch" (0/1), "power" or "other"
    constant: bool = False   # never changes in the recording: cannot drive anything identifiable


def classify_driver(name: str, values: np.ndarray) -> DriverInfo:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    mx = float(np.max(np.abs(v))) if v.size else 0.0
    uniq = np.unique(v) if v.size else np.array([])
    n = name.lower()
    if uniq.size <= 2 and set(np.round(uniq, 9)).issubset({0.0, 1.0}):
        kind = "switch"
    elif "rpm" in n or "speed" in n:
        kind = "speed"
    elif "power" in n or n.endswith("_w") or n.endswith("_kw"):
        kind = "power"
    else:
        kind = "other"
    return DriverInfo(name, mx, kind, bool(uniq.size <= 1))


def _is_coolant(name: str) -> bool:
    n = name.lower()
    return "coolant" in n or "mwf" in n or "oil" in n or "cutting_fluid" in n


def _is_door(name: str) -> bool:
    return "door" in name.lower()


def _ambient_boundary(spec: dict) -> str:
    """The boundary that stands for the hall air: named ambient/air/hall, else the first
    boundary driven by an environment input, else the first boundary."""
    bnds = spec["boundaries"]
    for b in bnds:
        if any(w in b.lower() for w in ("ambient", "air", "hall")):
            return b
    for b, d in bnds.items():
        t = d.get("temperature")
        if isinstance(t, str) and spec["inputs"].get(t, {}).get("kind") == "environment":
            return b
    return next(iter(bnds))


def _ensure_input(spec: dict, drv: DriverInfo) -> None:
    """Declare a recording column the twin does not know as a machine input."""
    if drv.name not in spec["inputs"]:
        spec["inputs"][drv.name] = {"kind": "machine", "unit": "", "default": 0.0}


def _unique(spec: dict, section: str, base: str) -> str:
    name, k = base, 2
    while name in spec.get(section, {}) or name in spec.get("nodes", {}) or name in spec.get("boundaries", {}):
        name, k = f"{base}_{k}", k + 1
    return name


def _ambient_link(spec: dict, node: str, amb: str) -> str:
    """Name of the node's link to the ambient boundary, created (G0 = 0) if missing."""
    for lname, d in spec["links"].items():
        if set(d["between"]) == {node, amb}:
            return lname
    lname = _unique(spec, "links", f"mm_{node}_{amb}")
    spec["links"][lname] = {"between": [node, amb], "conductance": 0.0,
                            "note": "added by the mismatch finder"}
    return lname


def _release(spec: dict, name: str) -> None:
    """Drop the twin's stated calibration range of a parameter the finder sets: its value is
    now a hypothesis that may lie outside that range (which would make the twin invalid)."""
    ((spec.get("calibration") or {}).get("parameters") or {}).pop(name, None)


def _sign_check(name: str, idx: int = 0) -> Callable[[np.ndarray], str | None]:
    def check(v: np.ndarray) -> str | None:
        return f"{name} = {v[idx]:.4g} < 0: wrong sign" if v[idx] < 0 else None
    return check


def _all(*checks) -> Callable[[np.ndarray], str | None]:
    def check(v: np.ndarray) -> str | None:
        for c in checks:
            r = c(v)
            if r:
                return r
        return None
    return check


def _range_check(name: str, idx: int, lo: float, hi: float, unit: str) -> Callable[[np.ndarray], str | None]:
    def check(v: np.ndarray) -> str | None:
        if not lo <= v[idx] <= hi:
            return f"{name} = {v[idx]:.4g} {unit} outside the physical range [{lo:g}, {hi:g}] {unit}"
        return None
    return check


# --------------------------------------------------------------------------------------
def heat_source(spec: dict, node: str, drv: DriverInfo) -> Candidate:
    umax = drv.max_abs or 1.0
    with_exponent = drv.kind in ("speed", "other")
    params = [ParamSpec("P_max", "W", -MAX_SOURCE_W * 2, MAX_SOURCE_W * 2, 20.0)]
    if with_exponent:
        params.append(ParamSpec("exponent", "-", 0.5, 3.0, 1.3))

    def apply(s: dict, v: np.ndarray) -> dict:
        _ensure_input(s, drv)
        n = float(v[1]) if with_exponent else 1.0
        name = _unique(s, "sources", f"mm_heat_{node}_{drv.name}")
        s["sources"][name] = {"node": node, "power": 0.0, "input": drv.name,
                              "coefficient": float(v[0]) / umax ** n, "exponent": n,
                              "note": "added by the mismatch finder (heat_source)"}
        return s

    checks = [_sign_check("P_max"), _range_check("P_max", 0, 0.0, MAX_SOURCE_W, "W")]
    if with_exponent:
        checks.append(_range_check("exponent", 1, 0.6, 2.5, ""))
    return Candidate("heat_source", node, drv.name, params, apply, _all(*checks))


def ambient_coupling(spec: dict, node: str) -> Candidate:
    amb = _ambient_boundary(spec)
    g_old = 0.0
    for d in spec["links"].values():
        if set(d["between"]) == {node, amb}:
            g_old = float(d["conductance"])
    params = [ParamSpec("dG", "W/K", -g_old, MAX_CONDUCTANCE_W_K * 2, max(0.05 * g_old, 0.5))]

    def apply(s: dict, v: np.ndarray) -> dict:
        ln = _ambient_link(s, node, amb)
        _release(s, f"links.{ln}.conductance")
        s["links"][ln]["conductance"] = max(0.0, float(s["links"][ln]["conductance"]) + float(v[0]))
        return s

    def check(v: np.ndarray) -> str | None:
        if g_old == 0.0 and v[0] < 0:
            return f"dG = {v[0]:.4g} W/K < 0 on a node without ambient link: wrong sign"
        if g_old + v[0] > MAX_CONDUCTANCE_W_K:
            return f"G = {g_old + v[0]:.4g} W/K above {MAX_CONDUCTANCE_W_K:g} W/K: not a machine structure"
        return None
    t_amb = spec["boundaries"][amb].get("temperature")
    return Candidate("ambient_coupling", node, t_amb if isinstance(t_amb, str) else None, params, apply, check)


def conduction(spec: dict, a: str, b: str) -> Candidate:
    """A conduction path between node ``a`` and node or non-ambient boundary ``b`` that the
    twin has no link for (target ``a/b``)."""
    params = [ParamSpec("G", "W/K", 0.0, MAX_CONDUCTANCE_W_K * 2, 2.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        s["links"][_unique(s, "links", f"mm_{a}_{b}")] = {
            "between": [a, b], "conductance": float(v[0]), "note": "added by the mismatch finder (conduction)"}
        return s
    return Candidate("conduction", f"{a}/{b}", None, params, apply,
                     _range_check("G", 0, 0.0, MAX_CONDUCTANCE_W_K, "W/K"))


def unlinked_pairs(spec: dict) -> list[tuple[str, str]]:
    """(node, node or non-ambient boundary) pairs without a link, in the description's order;
    if the description declares ``contacts`` (which places physically touch), only those pairs:
    heat does not conduct between parts that do not touch."""
    nodes = list(spec["nodes"])
    amb = _ambient_boundary(spec)
    others = nodes + [b for b in spec["boundaries"] if b != amb]
    linked = {frozenset(d["between"]) for d in spec["links"].values()}
    touching = _contacts(spec)
    return [(a, b) for i, a in enumerate(nodes) for b in others[i + 1:] if frozenset((a, b)) not in linked
            and (touching is None or frozenset((a, b)) in touching)]


def _contacts(spec: dict) -> set[frozenset] | None:
    """The declared touching pairs, or None when the description declares none (all pairs)."""
    declared = spec.get("contacts")
    return None if not declared else {frozenset(p) for p in declared}


def elastic_nodes(spec: dict, channel: str) -> list[str]:
    """Nodes an ``elastic_gain`` of ``channel`` may change: its terms, and, if the description
    declares ``contacts``, every node touching one of them that has no term yet (the channel's
    structural loop may pass through a part the twin left out of it; the term is then added
    from zero). Without a declaration, the existing terms only."""
    terms = list(spec["errors"][channel]["terms"])
    touching = _contacts(spec)
    if touching is None:
        return terms
    near = {x for pair in touching if pair & set(terms) for x in pair}
    return terms + [n for n in spec["nodes"] if n in near and n not in terms]


def time_lag_sensor(spec: dict, sensor: str) -> Candidate:
    lag0 = float(spec["sensors"][sensor].get("lag_s", 0.0))
    params = [ParamSpec("tau", "s", 1.0, 24 * 3600.0, 1800.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        s["sensors"][sensor]["lag_s"] = lag0 + float(v[0])
        return s
    return Candidate("time_lag", sensor, None, params, apply,
                     _range_check("tau", 0, *TAU_RANGE_S, "s"), affects=[f"{sensor}_c"])


def time_lag_error(spec: dict, channel: str) -> Candidate:
    params = [ParamSpec("tau", "s", 1.0, 24 * 3600.0, 1800.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        tau = float(v[0])
        terms = dict(s["errors"][channel]["terms"])
        new_terms = {}
        overrides = (s.get("calibration") or {}).get("parameters") or {}
        for node, g in terms.items():
            c = 1e-3 * float(s["nodes"][node]["capacity"])
            lag = _unique(s, "nodes", f"mm_lag_{channel}_{node}")
            s["nodes"][lag] = {"capacity": c, "note": f"added by the mismatch finder (time_lag of {channel})"}
            s["links"][_unique(s, "links", f"mm_{lag}")] = {"between": [node, lag], "conductance": c / tau}
            new_terms[lag] = g
            # the term's calibration range (if the twin states one) moves with it to the lag node
            old = f"errors.{channel}.terms.{node}"
            if old in overrides:
                overrides[f"errors.{channel}.terms.{lag}"] = overrides.pop(old)
        s["errors"][channel]["terms"] = new_terms
        return s
    return Candidate("time_lag", channel, None, params, apply,
                     _range_check("tau", 0, *TAU_RANGE_S, "s"), affects=[channel])


def speed_dependent_convection(spec: dict, node: str, drv: DriverInfo) -> Candidate:
    amb = _ambient_boundary(spec)
    vmax = drv.max_abs or 1.0
    params = [ParamSpec("dG_max", "W/K", 0.0, MAX_CONDUCTANCE_W_K * 2, 1.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        _ensure_input(s, drv)
        ln = _ambient_link(s, node, amb)
        vw = s["links"][ln].setdefault("varies_with", {})
        old = vw.get(drv.name, {"per_unit": 0.0, "exponent": CONVECTION_EXPONENT})
        e = float(old.get("exponent", CONVECTION_EXPONENT))
        vw[drv.name] = {"per_unit": float(old.get("per_unit", 0.0)) + float(v[0]) / vmax ** e, "exponent": e}
        return s
    return Candidate("speed_dependent_convection", node, drv.name, params, apply,
                     _range_check("dG_max", 0, 0.0, MAX_CONDUCTANCE_W_K, "W/K"))


def coolant(spec: dict, node: str, drv: DriverInfo) -> Candidate:
    cool = next((b for b in spec["boundaries"] if _is_coolant(b)), None)
    params = [ParamSpec("G_on", "W/K", 0.0, MAX_CONDUCTANCE_W_K * 2, 2.0)]
    if cool is None:
        params.append(ParamSpec("T_coolant", "degC", 0.0, 60.0, 20.0))

    def apply(s: dict, v: np.ndarray) -> dict:
        _ensure_input(s, drv)
        b = cool
        if b is None:
            b = _unique(s, "boundaries", "mm_coolant")
            s["boundaries"][b] = {"temperature": float(v[1])}
        ln = _unique(s, "links", f"mm_{node}_{b}")
        s["links"][ln] = {"between": [node, b], "conductance": 0.0,
                          "varies_with": {drv.name: {"per_unit": float(v[0]), "exponent": 1.0}},
                          "note": "added by the mismatch finder (coolant)"}
        return s
    checks = [_range_check("G_on", 0, 0.0, MAX_CONDUCTANCE_W_K, "W/K")]
    if cool is None:
        checks.append(_range_check("T_coolant", 1, 5.0, 45.0, "degC"))
    return Candidate("coolant", node, drv.name, params, apply, _all(*checks))


def door_event(spec: dict, node: str, drv: DriverInfo) -> Candidate:
    amb = _ambient_boundary(spec)
    params = [ParamSpec("dG_open", "W/K", 0.0, MAX_CONDUCTANCE_W_K * 2, 2.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        _ensure_input(s, drv)
        ln = _ambient_link(s, node, amb)
        vw = s["links"][ln].setdefault("varies_with", {})
        old = float(vw.get(drv.name, {}).get("per_unit", 0.0))
        vw[drv.name] = {"per_unit": old + float(v[0]), "exponent": 1.0}
        return s
    return Candidate("door_event", node, drv.name, params, apply,
                     _range_check("dG_open", 0, 0.0, MAX_CONDUCTANCE_W_K, "W/K"))


def sensor_bias(spec: dict, sensor: str) -> Candidate:
    b0 = float(spec["sensors"][sensor].get("bias", 0.0))
    res = float(spec["sensors"][sensor].get("resolution", 0.0))
    params = [ParamSpec("bias", "K", -4 * MAX_BIAS_K, 4 * MAX_BIAS_K, 0.5)]

    def apply(s: dict, v: np.ndarray) -> dict:
        _release(s, f"sensors.{sensor}.bias")
        s["sensors"][sensor]["bias"] = b0 + float(v[0])
        return s

    def within_quantisation(v: np.ndarray) -> str | None:
        if res > 0 and abs(v[0]) <= 0.5 * res:
            return (f"bias = {v[0]:.3g} K within half the sensor's {res:g} K resolution: "
                    "indistinguishable from quantisation")
        return None
    return Candidate("sensor_bias", sensor, None, params, apply,
                     _all(_range_check("bias", 0, -MAX_BIAS_K, MAX_BIAS_K, "K"), within_quantisation),
                     affects=[f"{sensor}_c"])


def elastic_gain(spec: dict, channel: str, node: str) -> Candidate:
    g0 = float(spec["errors"][channel]["terms"].get(node, 0.0))
    params = [ParamSpec("d_gain", "um/K", -4 * MAX_ELASTIC_UM_K, 4 * MAX_ELASTIC_UM_K, 1.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        _release(s, f"errors.{channel}.terms.{node}")
        s["errors"][channel]["terms"][node] = g0 + float(v[0])
        return s
    return Candidate("elastic_gain", f"{channel}/{node}", None, params, apply,
                     _range_check("gain", 0, -MAX_ELASTIC_UM_K - g0, MAX_ELASTIC_UM_K - g0, "um/K (change)"),
                     affects=[channel])


def periodic_load(spec: dict, node: str) -> Candidate:
    # fitted as a sin + b cos (linear, no phase wrap-around), stored as amplitude and phase
    params = [ParamSpec("a_sin", "W", -MAX_SOURCE_W, MAX_SOURCE_W, 20.0),
              ParamSpec("b_cos", "W", -MAX_SOURCE_W, MAX_SOURCE_W, 0.0)]

    def apply(s: dict, v: np.ndarray) -> dict:
        amp, phase = periodic_amplitude_phase(v)
        name = _unique(s, "sources", f"mm_periodic_{node}")
        s["sources"][name] = {"node": node, "power": 0.0,
                              "periodic": {"amplitude": amp, "period_s": DAY_S, "phase_s": phase},
                              "note": "added by the mismatch finder (periodic_load, 24 h)"}
        return s

    def check(v: np.ndarray) -> str | None:
        amp, _ = periodic_amplitude_phase(v)
        return (f"amplitude = {amp:.4g} W above {MAX_SOURCE_W:g} W: energy that cannot be"
                if amp > MAX_SOURCE_W else None)
    return Candidate("periodic_load", node, None, params, apply, check)


def periodic_amplitude_phase(v) -> tuple[float, float]:
    """a sin(wt) + b cos(wt) = A sin(w (t - phase)), A >= 0, phase in [0, 24 h)."""
    a, b = float(v[0]), float(v[1])
    amp = math.hypot(a, b)
    phi = math.atan2(b, a)
    return amp, float((-phi / (2 * math.pi) * DAY_S) % DAY_S)


# --------------------------------------------------------------------------------------
def candidates(spec: dict, drivers: dict[str, DriverInfo], channels: list[str],
               effects: tuple[str, ...] = EFFECTS) -> list[Candidate]:
    """Every candidate of the library for a machine and the recording's drivers.

    ``drivers``: the recording's input columns (known to the twin or not). ``channels``:
    the channels shared by twin and recording (sensor columns ``<id>_c`` and errors)."""
    nodes = list(spec["nodes"])
    sensors = [s for s in spec["sensors"] if f"{s}_c" in channels]
    errors = [e for e in spec["errors"] if e in channels]
    env_inputs = {n for n, d in spec["inputs"].items() if d.get("kind") == "environment"}
    machine_drivers = [d for d in drivers.values() if d.name not in env_inputs and d.max_abs > 0
                       and not d.constant]
    out: list[Candidate] = []
    for node in nodes:
        if "heat_source" in effects:
            for d in machine_drivers:
                out.append(heat_source(spec, node, d))
        if "ambient_coupling" in effects:
            out.append(ambient_coupling(spec, node))
        if "speed_dependent_convection" in effects:
            out += [speed_dependent_convection(spec, node, d) for d in machine_drivers if d.kind == "speed"]
        if "coolant" in effects:
            out += [coolant(spec, node, d) for d in machine_drivers
                    if d.kind == "switch" and _is_coolant(d.name)]
        if "door_event" in effects:
            out += [door_event(spec, node, d) for d in machine_drivers
                    if d.kind == "switch" and _is_door(d.name)]
        if "periodic_load" in effects:
            out.append(periodic_load(spec, node))
    if "conduction" in effects:
        out += [conduction(spec, a, b) for a, b in unlinked_pairs(spec)]
    if "time_lag" in effects:
        out += [time_lag_sensor(spec, s) for s in sensors]
        out += [time_lag_error(spec, e) for e in errors]
    if "sensor_bias" in effects:
        out += [sensor_bias(spec, s) for s in sensors]
    if "elastic_gain" in effects:
        out += [elastic_gain(spec, e, n) for e in errors for n in elastic_nodes(spec, e)]
    return out
