"""Named, seeded scenarios (``--scenario``): input time lines for the presets.

Each scenario belongs to one or more machines and has a default duration and step. The same
(machine, scenario, hours, seed, step) always gives the same time line. Sources of the
numbers: the TALC thesis (talc-*, load-case-*, fe-two-source: spec §2.6, §4.7-4.9), the
Swiss-lathe thesis (lathe-*: spec §4.2, §6, §10) and the FL_THERMAL README
(fl-thermal-programme).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from thermal_twin.inputs_timeline import InputsTimeline
from thermal_twin.profiles import (DoorDrop, de_bruijn_pairs, first_order, hall_ambient, on_off,
                                   random_levels, step_programme)

H = 3600.0
Builder = Callable[[np.ndarray, np.random.Generator], dict]


class ScenarioError(ValueError):
    """Unknown scenario, or a scenario that does not fit the machine."""


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    hours: float
    step_s: float
    builders: dict[str, Builder]          # machine name -> builder(t, rng) -> input arrays


# ---------------------------------------------------------------- nmv5000 (5-axis, C table)
C_LEVELS = np.arange(0.0, 1201.0, 100.0)
C_PROBS = np.where(C_LEVELS == 0, 0.25, 0.75 / (len(C_LEVELS) - 1))


def _c_random(t, rng, hold=(0.5 * H, 4 * H)):
    return random_levels(t, rng, C_LEVELS, hold, C_PROBS)


def _mwf_supply(t, amb, coolant_on):
    """MWF tank (uncontrolled): follows the hall with a 3 h lag, warmed by about 6 K while
    its pump circulates the fluid (pump losses into a few hundred litres)."""
    target = amb + 1.0 + 6.0 * coolant_on
    return first_order(t, target, 3 * H, start=float(amb[0] + 1.0))


def talc_178h_dry(t, rng):
    amb = hall_ambient(t, rng, mean=21.0, day_amplitude=3.0, drift_per_day=1.0)
    cool = np.zeros_like(t)
    return {"c_speed_rpm": _c_random(t, rng), "coolant_on": cool,
            "coolant_temp_degc": _mwf_supply(t, amb, cool), "ambient_degc": amb}


def talc_144h_mwf(t, rng):
    drops = [DoorDrop(63.5 * H, depth=3.0, fall_s=1500.0), DoorDrop(111.2 * H, depth=3.0, fall_s=1500.0)]
    amb = hall_ambient(t, rng, mean=19.5, day_amplitude=0.6, drift_per_day=0.3, door_drops=drops)
    cool = on_off(t, rng, on_s=(1 * H, 6 * H), off_s=(1 * H, 6 * H))
    return {"c_speed_rpm": _c_random(t, rng), "coolant_on": cool,
            "coolant_temp_degc": _mwf_supply(t, amb, cool), "ambient_degc": amb}


def _load_case(mwf: bool, optimised_h: float = 0.0):
    def build(t, rng):
        amb = hall_ambient(t, rng, mean=21.0, day_amplitude=2.5, drift_per_day=0.8)
        c = _c_random(t, rng)
        if optimised_h > 0:
            seq = de_bruijn_pairs(5)                          # levels 0, 300, ..., 1200
            changes = [(1.5 * H * i, 300.0 * s) for i, s in enumerate(seq)]
            opt = step_programme(t, changes)
            c = np.where(t < optimised_h * H, opt, c)
        cool = on_off(t, rng, on_s=(1 * H, 6 * H), off_s=(1 * H, 6 * H)) if mwf else np.zeros_like(t)
        return {"c_speed_rpm": c, "coolant_on": cool, "coolant_temp_degc": _mwf_supply(t, amb, cool),
                "ambient_degc": amb}
    return build


def _iso230_3(speed_input: str, speed: float, extra: dict | None = None):
    """ISO 230-3 style: 4 h at constant speed, then 4 h stopped; steady hall."""
    def build(t, rng):
        amb = np.full_like(t, 20.0) + hall_ambient(t, rng, mean=0.0, day_amplitude=0.2, drift_per_day=0.05)
        out = {speed_input: np.where(t < 4 * H, speed, 0.0), "ambient_degc": amb}
        for k, v in (extra or {}).items():
            out[k] = np.full_like(t, v)
        return out
    return build


# ---------------------------------------------------------------- registry
SCENARIOS: dict[str, Scenario] = {}


def _register(s: Scenario) -> None:
    SCENARIOS[s.name] = s


_register(Scenario("talc-178h-dry", "random C-axis speeds 0-1200 1/min held 0.5-4 h, dry; "
                   "non-air-conditioned hall: +-3 degC day/night plus a drifting daily mean "
                   "(TALC thesis §6.4.2)", 178.0, 60.0, {"nmv5000": talc_178h_dry}))
_register(Scenario("talc-144h-mwf", "random C-axis speeds, MWF switched on/off at random (1-6 h), "
                   "heated winter hall with two door drops of 3 degC in 25 min at 63.5 h and 111.2 h "
                   "(TALC thesis §6.4.3)", 144.0, 60.0, {"nmv5000": talc_144h_mwf}))
_register(Scenario("load-case-A", "96 h random C-axis speed profile, dry (spec §4.7)", 96.0, 60.0,
                   {"nmv5000": _load_case(False)}))
_register(Scenario("load-case-B", "96 h random C-axis speed profile, dry, another draw (spec §4.7)",
                   96.0, 60.0, {"nmv5000": _load_case(False)}))
_register(Scenario("load-case-C", "104 h: first 32 h the 'optimised' pattern (0-1200 1/min in 300 "
                   "steps, every pair of successive speeds held 1.5 h), then random (spec §4.7)",
                   104.0, 60.0, {"nmv5000": _load_case(False, optimised_h=32.0)}))
_register(Scenario("load-case-D", "144 h random C-axis speeds with MWF on/off (spec §4.7)", 144.0, 60.0,
                   {"nmv5000": _load_case(True)}))

def scenario_names(machine: str | None = None) -> list[str]:
    return sorted(n for n, s in SCENARIOS.items() if machine is None or machine in s.builders)


def make_timeline(machine: str, scenario: str, hours: float | None = None, seed: int = 0,
                  step_s: float | None = None) -> InputsTimeline:
    """The input time line of ``scenario`` for preset ``machine`` (seeded, reproducible)."""
    if scenario not in SCENARIOS:
        raise ScenarioError(f"scenario {scenario!r} is unknown (scenarios: {', '.join(scenario_names())})")
    s = SCENARIOS[scenario]
    if machine not in s.builders:
        raise ScenarioError(f"scenario {scenario!r} does not fit machine {machine!r} "
                            f"(it runs on: {', '.join(s.builders)}; scenarios for {machine}: "
                            f"{', '.join(scenario_names(machine)) or 'none'})")
    hours = s.hours if hours is None else float(hours)
    step = s.step_s if step_s is None else float(step_s)
    if not hours > 0:
        raise ScenarioError(f"hours: {hours!r} must be > 0")
    if not step > 0:
        raise ScenarioError(f"step_s: {step!r} must be > 0")
    t = np.arange(0.0, hours * H + 0.5 * step, step)
    # the scenario name is part of the seed: load-case-A and -B are different draws
    rng = np.random.default_rng([int(seed), _stable_hash(scenario)])
    values = s.builders[machine](t, rng)
    return InputsTimeline(t, values, name=scenario)


def _stable_hash(text: str) -> int:
    h = 2166136261
    for ch in text.encode():
        h = ((h ^ ch) * 16777619) & 0xFFFFFFFF
    return h
