"""Named, seeded scenarios (``--scenario``): input time lines for the presets.

Each scenario belongs to one or more machines and has a default duration and step. The same
(machine, scenario, hours, seed, step) always gives the same time line. Sources of the
numbers: the TALC thesis (talc-*, load-case-*, fe-two-source: spec §2.6, §4.7-4.9), the
Swiss-lathe thesis (lathe-*: spec §4.2, §6, §10). A dataset's own programme lives with the
dataset and joins through the entry-point group ``thermal_twin.sim.scenarios`` ("name = module:SCENARIO",
e.g. thermal_eval's ``fl-thermal-programme``); plug-ins are loaded on the first look-up.
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Callable

import numpy as np

from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.sim.profiles import (DoorDrop, de_bruijn_pairs, first_order, hall_ambient, on_off,
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
    seed_name: str = ""                   # draw random numbers as this scenario does (paired sets)


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


def _stratified_durations(rng, n: int, lo_s: float, hi_s: float) -> np.ndarray:
    """``n`` durations in [lo_s, hi_s], one from each of n equal strata, in random order (a
    Latin-hypercube design in one dimension: short and long phases both occur)."""
    u = (np.arange(n) + rng.uniform(0.0, 1.0, n)) / n
    return rng.permutation(lo_s + u * (hi_s - lo_s))


def type_mwf_hall_phases(t, rng):
    """Prior training (virtual experiment of the type): MWF switching at every phase of a
    swinging hall. The on/off durations are a stratified design over 1-6 h, so the switches
    fall at all hours of the day/night cycle (+-3 degC, the type's widest hall, drifting as the
    load cases' hall) and both short and long phases occur. No door drops: with them and a
    1 K/day drift a draw can take the hall to 12 degC (docs/talc.md, "A rate state in the observer")."""
    n = int(np.ceil(t[-1] / (3.5 * H))) + 2
    on, off = _stratified_durations(rng, n, 1 * H, 6 * H), _stratified_durations(rng, n, 1 * H, 6 * H)
    edges = np.cumsum(np.ravel(np.column_stack([off, on])))
    cool = (np.searchsorted(edges, t, side="right") % 2).astype(float)
    amb = hall_ambient(t, rng, mean=21.0, day_amplitude=3.0, drift_per_day=0.8)
    return {"c_speed_rpm": _c_random(t, rng), "coolant_on": cool,
            "coolant_temp_degc": _mwf_supply(t, amb, cool), "ambient_degc": amb}


def _iso230_3(speeds: dict[str, float]):
    """ISO 230-3 style: 4 h at constant speed of the heat sources, then 4 h stopped; steady hall."""
    def build(t, rng):
        amb = hall_ambient(t, rng, mean=20.0, day_amplitude=0.2, drift_per_day=0.05)
        out = {k: np.where(t < 4 * H, v, 0.0) for k, v in speeds.items()}
        out["ambient_degc"] = amb
        return out
    return build


# ---------------------------------------------------------------- swiss-lathe
S1_LEVELS = np.arange(0.0, 6001.0, 500.0)
S11_LEVELS = np.arange(0.0, 4001.0, 500.0)


def _lathe_ambient(t, rng):
    """Hall heated by day with thermostat 'teeth', unheated at night (lathe thesis §6.2)."""
    return hall_ambient(t, rng, mean=21.0, day_amplitude=1.5, drift_per_day=0.5,
                        heating_teeth=0.8, teeth_period_s=1800.0)


def lathe_random_speed(t, rng):
    """~70 h of random S1/S11 speeds held 0.5-3 h; cutting-oil set-point changes at 30 h
    and 50 h (oil follows its set-point with a 45 min lag)."""
    s1 = random_levels(t, rng, S1_LEVELS, (0.5 * H, 3 * H))
    s11 = random_levels(t, rng, S11_LEVELS, (0.5 * H, 3 * H))
    setpoint = step_programme(t, [(0.0, 24.0), (30 * H, float(rng.uniform(32, 40))),
                                  (50 * H, float(rng.uniform(15, 20)))])
    return {"s1_rpm": s1, "s11_rpm": s11, "oil_on": np.ones_like(t),
            "oil_temp_degc": first_order(t, setpoint, 0.75 * H), "ambient_degc": _lathe_ambient(t, rng)}


def lathe_oil_steps(t, rng):
    """Random S1/S11 speeds; cutting-oil set-point stepped every 6-12 h within 15-40 degC
    (the most disruptive event for a data-driven model, lathe thesis §7)."""
    s1 = random_levels(t, rng, S1_LEVELS, (0.5 * H, 3 * H))
    s11 = random_levels(t, rng, S11_LEVELS, (0.5 * H, 3 * H))
    setpoint = random_levels(t, rng, np.arange(15.0, 40.1, 2.5), (6 * H, 12 * H))
    return {"s1_rpm": s1, "s11_rpm": s11, "oil_on": np.ones_like(t),
            "oil_temp_degc": first_order(t, setpoint, 0.75 * H, start=float(setpoint[0])),
            "ambient_degc": _lathe_ambient(t, rng)}


def _stops(t, rng, n, first_s, min_gap_s, dur_s):
    """n stops at random times after first_s, at least min_gap_s apart: (start, end) list."""
    starts, last = [], first_s
    end = t[-1] - 0.5 * H
    for _ in range(n):
        lo = last + min_gap_s if starts else first_s
        if lo >= end:
            break
        st = float(rng.uniform(lo, min(end, lo + 2 * min_gap_s)))
        starts.append((st, st + float(rng.uniform(*dur_s))))
        last = st
    return starts


def lathe_door_openings(t, rng):
    """8 h at constant S1 4000 / S11 3000 1/min with several stops of 5-30 min during which
    the door is open and all spindles stand still; oil drifts 24 -> 31 degC (thesis §6.2.2)."""
    stops = _stops(t, rng, 4, 1.5 * H, 1.2 * H, (5 * 60.0, 30 * 60.0))
    stopped = np.zeros_like(t)
    for a, b in stops:
        stopped[(t >= a) & (t < b)] = 1.0
    oil = first_order(t, np.full_like(t, 31.5), 3 * H, start=24.0)
    return {"s1_rpm": np.where(stopped > 0, 0.0, 4000.0), "s11_rpm": np.where(stopped > 0, 0.0, 3000.0),
            "oil_on": 1.0 - stopped, "oil_temp_degc": oil, "door_open": stopped,
            "ambient_degc": _lathe_ambient(t, rng)}


def lathe_test_piece(t, rng):
    """The thermal test piece (thesis ch. 7): 8 h of 6 min part cycles at S1 4000 1/min,
    the driven tools (S11 3000 1/min) running 2 min of each cycle for the hexagon and holes;
    a ~30 min lunch stop with the door open after 4 h; oil rising 20 -> 27 degC."""
    cycle = 360.0
    in_cycle = t % cycle
    s11 = np.where((in_cycle >= 120.0) & (in_cycle < 240.0), 3000.0, 0.0)
    lunch_start = 4 * H + float(rng.uniform(-0.25, 0.25)) * H
    lunch = (t >= lunch_start) & (t < lunch_start + float(rng.uniform(25, 35)) * 60.0)
    oil = first_order(t, np.full_like(t, 27.5), 4 * H, start=20.0)
    return {"s1_rpm": np.where(lunch, 0.0, 4000.0), "s11_rpm": np.where(lunch, 0.0, s11),
            "oil_on": np.where(lunch, 0.0, 1.0), "oil_temp_degc": oil, "door_open": lunch.astype(float),
            "ambient_degc": _lathe_ambient(t, rng)}


# ---------------------------------------------------------------- FE three-body (§2.6)
def _two_source_draw(t, rng):
    """Random heat-flux patterns for Q1 and Q2: levels 0-100 W held 1-6 h."""
    levels = np.arange(0.0, 101.0, 20.0)
    return (random_levels(t, rng, levels, (1 * H, 6 * H)), random_levels(t, rng, levels, (1 * H, 6 * H)))


def fe_two_source(t, rng):
    q1, q2 = _two_source_draw(t, rng)
    return {"q1_w": q1, "q2_w": q2, "ambient_degc": np.full_like(t, 20.0)}


def fe_two_source_swapped(t, rng):
    """The validation set of §2.6: the same draw as fe-two-source (same seed) with Q1 and
    Q2 switched and scaled (x1.3 and x0.7)."""
    q1, q2 = _two_source_draw(t, rng)
    return {"q1_w": 1.3 * q2, "q2_w": 0.7 * q1, "ambient_degc": np.full_like(t, 20.0)}


# ---------------------------------------------------------------- registry
#: entry-point group of scenarios other packages add ("name = module:SCENARIO", a Scenario)
PLUGIN_GROUP = "thermal_twin.sim.scenarios"


class _Registry(dict):
    """The scenarios by name; the plug-ins of :data:`PLUGIN_GROUP` join on the first look-up (not
    at import: a plug-in module imports this one)."""

    _loaded = False

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        for ep in entry_points(group=PLUGIN_GROUP):
            s = ep.load()
            if not isinstance(s, Scenario) or s.name != ep.name:
                raise ScenarioError(f"{PLUGIN_GROUP} entry point {ep.name!r} ({ep.value}) is not a Scenario "
                                    f"named {ep.name!r}")
            dict.setdefault(self, s.name, s)

    def __getitem__(self, k):
        self._load()
        return dict.__getitem__(self, k)

    def __contains__(self, k) -> bool:
        self._load()
        return dict.__contains__(self, k)

    def __iter__(self):
        self._load()
        return dict.__iter__(self)

    def __len__(self) -> int:
        self._load()
        return dict.__len__(self)

    def get(self, k, default=None):
        self._load()
        return dict.get(self, k, default)

    def items(self):
        self._load()
        return dict.items(self)

    def keys(self):
        self._load()
        return dict.keys(self)

    def values(self):
        self._load()
        return dict.values(self)


SCENARIOS: dict[str, Scenario] = _Registry()


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

_register(Scenario("type-mwf-hall-phases", "prior training programme (a designed virtual experiment, no "
                   "evaluated case): 144 h random C-axis speeds, MWF on/off for stratified 1-6 h phases "
                   "that fall at every phase of a +-3 degC day/night hall", 144.0, 60.0,
                   {"nmv5000": type_mwf_hall_phases}))
_register(Scenario("iso230-3", "ISO 230-3 style warm-up and cool-down: 4 h at a constant high speed of the "
                   "main heat source, then 4 h stopped, steady hall", 8.0, 30.0,
                   {"nmv5000": _iso230_3({"c_speed_rpm": 1200.0}),
                    "swiss_lathe": _iso230_3({"s1_rpm": 6000.0, "s11_rpm": 3000.0}),
                    "spindle_stand": _iso230_3({"spindle_rpm": 5000.0})}))
_register(Scenario("lathe-random-speed", "~70 h random S1 (0-6000) and S11 (0-4000 1/min) speeds, "
                   "cutting-oil set-point changes at 30 h and 50 h, day/night hall with heating teeth "
                   "(lathe thesis §6.2.1)", 70.0, 30.0, {"swiss_lathe": lathe_random_speed}))
_register(Scenario("lathe-door-openings", "8 h constant S1/S11 with stops and door openings; "
                   "driven tools cool by up to 20 degC within minutes (lathe thesis §6.2.2)", 8.0, 30.0,
                   {"swiss_lathe": lathe_door_openings}))
_register(Scenario("lathe-oil-steps", "random S1/S11 speeds with cutting-oil set-point steps within "
                   "15-40 degC every 6-12 h", 48.0, 30.0, {"swiss_lathe": lathe_oil_steps}))
_register(Scenario("lathe-test-piece", "thermal test piece run: 8 h of 6 min part cycles, S1 4000 and "
                   "driven tools 3000 1/min, lunch stop with the door open (lathe thesis ch. 7)", 8.0, 30.0,
                   {"swiss_lathe": lathe_test_piece}))
_register(Scenario("fe-two-source", "48 h random heat fluxes Q1 (base front) and Q2 (spindle top), "
                   "5 min steps (TALC thesis §4.2 FE study, training set)", 48.0, 300.0,
                   {"fe_three_body": fe_two_source}))
_register(Scenario("fe-two-source-swapped", "validation set of fe-two-source: the same loads switched "
                   "between Q1 and Q2 and scaled", 48.0, 300.0, {"fe_three_body": fe_two_source_swapped},
                   seed_name="fe-two-source"))


def _key(machine: str) -> str:
    return machine.replace("-", "_")


def scenario_names(machine: str | None = None) -> list[str]:
    return sorted(n for n, s in SCENARIOS.items() if machine is None or _key(machine) in s.builders)


def make_timeline(machine: str, scenario: str, hours: float | None = None, seed: int = 0,
                  step_s: float | None = None) -> InputsTimeline:
    """The input time line of ``scenario`` for preset ``machine`` (seeded, reproducible)."""
    if scenario not in SCENARIOS:
        raise ScenarioError(f"scenario {scenario!r} is unknown (scenarios: {', '.join(scenario_names())})")
    s = SCENARIOS[scenario]
    if _key(machine) not in s.builders:
        shown = _key(machine).replace("_", "-")
        raise ScenarioError(f"scenario {scenario!r} does not fit machine {shown!r} "
                            f"(it runs on: {', '.join(b.replace('_', '-') for b in s.builders)}; scenarios for {shown}: "
                            f"{', '.join(scenario_names(machine)) or 'none'})")
    hours = s.hours if hours is None else float(hours)
    step = s.step_s if step_s is None else float(step_s)
    if not hours > 0:
        raise ScenarioError(f"hours: {hours!r} must be > 0")
    if not step > 0:
        raise ScenarioError(f"step_s: {step!r} must be > 0")
    t = np.arange(0.0, hours * H + 0.5 * step, step)
    # the scenario name is part of the seed: load-case-A and -B are different draws
    rng = np.random.default_rng([int(seed), _stable_hash(s.seed_name or scenario)])
    values = s.builders[_key(machine)](t, rng)
    return InputsTimeline(t, values, name=scenario)


def _stable_hash(text: str) -> int:
    h = 2166136261
    for ch in text.encode():
        h = ((h ^ ch) * 16777619) & 0xFFFFFFFF
    return h
