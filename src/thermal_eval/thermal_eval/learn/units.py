"""Units of a machine type whose physics differs from the type's twin beyond its tolerances:
the test bed of ``thermal-comp bench learn``. Each unit is the type's unit-to-unit instance
(thermal_twin.machine.instance) plus one structural difference drawn from a seed:

- ``extra_source``: a heat source the twin lacks, on a structural body, driven by a machine input
- ``links``: one or two structure-to-hall links x0.5 or x2 (beyond the +-20 % tolerance)
- ``gain``: one thermo-elastic term x1.4-1.7 (beyond +-10 %)
- ``hall_bias``: the hall sensor reads 0.4-0.8 K off (the twin's boundary follows it)
- ``chiller``: a cooling circuit that follows the hall instead of holding its set-point
- ``hall_drift``: the hall sensor is 0.1-0.4 K off and drifts 0.1-0.3 K a day

Only the nmv5000 type is covered (its structure names are used). No rclpy.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from thermal_twin.machine.instance import machine_instance
from thermal_twin.machine.schema import Machine, load_machine

KINDS = ("extra_source", "links", "gain", "hall_bias", "chiller", "hall_drift")
HALL_LINKS = ("bed_ambient", "column_ambient", "air_ambient", "cradle_air")
STRUCTURE = ("column", "bed", "cradle")


@dataclass
class Unit:
    name: str
    kind: str
    truth: str              # what differs, in words (never shown to the learner)
    machine: Machine


def _extra_source(spec: dict, rng) -> str:
    node = str(rng.choice(STRUCTURE))
    watts = float(rng.uniform(60.0, 160.0))          # at 1200 1/min
    spec["sources"]["unit_extra"] = {"node": node, "input": "c_speed_rpm", "coefficient": watts / 1200.0,
                                     "exponent": 1.0}
    return f"extra source on {node}: {watts:.0f} W at 1200 1/min, linear in C speed"


def _links(spec: dict, rng) -> str:
    picked = rng.choice(HALL_LINKS, size=int(rng.integers(1, 3)), replace=False)
    words = []
    for name in picked:
        f = float(rng.choice([0.5, 2.0]))
        spec["links"][str(name)]["conductance"] *= f
        words.append(f"{name} x{f:g}")
    return "links " + ", ".join(words)


def _gain(spec: dict, rng) -> str:
    ch = str(rng.choice(["E_Y0C", "E_Z0T", "E_X0C"]))
    terms = spec["errors"][ch]["terms"]
    node = str(rng.choice(sorted(terms)))
    f = float(rng.uniform(1.4, 1.7))
    terms[node] *= f
    return f"{ch}.{node} x{f:.2f}"


def _hall_bias(spec: dict, rng) -> str:
    b = float(rng.choice([-1, 1]) * rng.uniform(0.4, 0.8))
    spec["sensors"]["ambient"]["bias"] = b
    return f"hall sensor bias {b:+.2f} K"


def _chiller(spec: dict, rng) -> str:
    spec["boundaries"]["cooler"] = {"temperature": "ambient_degc"}
    return "C-axis chiller follows the hall instead of holding 22 degC"


def _hall_drift(spec: dict, rng) -> str:
    b = float(rng.choice([-1, 1]) * rng.uniform(0.1, 0.4))
    d = float(rng.choice([-1, 1]) * rng.uniform(0.1, 0.3)) / 24.0
    spec["sensors"]["ambient"]["bias"] = b
    spec["sensors"]["ambient"]["drift_k_per_h"] = d
    return f"hall sensor bias {b:+.2f} K, drift {24.0 * d:+.2f} K/day"


_MAKERS = {"extra_source": _extra_source, "links": _links, "gain": _gain, "hall_bias": _hall_bias,
           "chiller": _chiller, "hall_drift": _hall_drift}


def structural_unit(kind: str, seed: int, machine: str = "nmv5000") -> Unit:
    """Unit ``seed`` of ``machine`` with one structural difference of ``kind`` (module docstring)."""
    if kind not in _MAKERS:
        raise ValueError(f"unit kind {kind!r} is none of {list(KINDS)}")
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    spec = copy.deepcopy(machine_instance(machine, seed))
    truth = _MAKERS[kind](spec, rng)
    return Unit(f"{machine} unit #{seed} ({kind})", kind, truth, load_machine(spec))
