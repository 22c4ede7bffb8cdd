"""Procedurally drawn concealed-effect cases: a benchmark of the mismatch finder nobody tuned to.

:func:`draw_case` draws case ``index`` of ``seed`` from ``numpy.random.default_rng([seed, index])``
alone, so any case is reproducible by itself. A case picks a preset (every one of
:func:`thermal_twin.machine.presets.preset_names`), one of its scenarios or a generic seeded
programme, a recording length and step, and what is concealed:

- ``named``: one effect of the finder's vocabulary (type drawn uniformly among the types the
  machine and programme allow, then a candidate: target and driver) with its size set so the
  most affected channel moves by ``size`` times its noise RMS (barely detectable 1 to large 30,
  log-uniform), sometimes switched on part-way (``onset_h``, 1 h first-order blend);
- ``two``: two effects of different types;
- ``unnamed``: physics outside the vocabulary: a sensor's linear drift, a quadratic
  thermo-elastic term, a speed x temperature product term, a play (hysteresis) loop on a
  thermo-elastic term, a sensor moved to another body;
- ``none``: nothing concealed.

The recording (:func:`thermal_eval.diagnose.random_recording.case_recording`) has the generator's own noise (white, AR(1) or random
walk, level drawn), quantisation, dropped rows and a clock offset between the inputs and the
measured channels; the true machine's own sensor noise is switched off so that the drawn
noise is the only one.
"""
from __future__ import annotations

import copy
import dataclasses
import functools
import math

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_eval.diagnose.concealed import HiddenEffect
from thermal_twin.diagnose.effects import candidates, classify_driver
from thermal_twin.machine.presets import preset_names
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.sim.scenarios import make_timeline, scenario_names
from thermal_twin.sim.simulate import simulate

KINDS = ("named", "two", "unnamed", "none")
KIND_P = (0.55, 0.15, 0.15, 0.15)
OOV_KINDS = ("sensor_drift", "quadratic_elastic", "product", "hysteresis", "moved_sensor")
SIZE_RANGE = (1.0, 30.0)          # effect RMS / noise RMS on the most affected channel
HOURS_RANGE = (24.0, 72.0)
MAX_ROWS = 1500                   # the step grows so a case stays diagnosable in minutes


@dataclasses.dataclass(frozen=True)
class Oov:
    """Out-of-vocabulary physics: ``kind`` of :data:`OOV_KINDS`, ``target`` (sensor id, or
    ``channel/node``; ``sensor->node`` for a moved sensor) and its scale."""

    kind: str
    target: str
    value: float = 0.0

    @property
    def key(self) -> str:
        return f"unnamed:{self.kind}:{self.target}"


@dataclasses.dataclass(frozen=True)
class RandomCase:
    """Everything drawn for one case (the draw is all; :func:`case_recording` builds it)."""

    seed: int
    index: int
    twin: str
    scenario: str
    hours: float
    step_s: float
    kind: str
    hidden: tuple[HiddenEffect, ...] = ()
    oov: tuple[Oov, ...] = ()
    size: float = 0.0
    onset_h: float = 0.0
    noise: dict = dataclasses.field(default_factory=dict)

    @property
    def label(self) -> str:
        what = "+".join([h.key for h in self.hidden] + [o.key for o in self.oov]) or "none"
        return f"{self.seed}/{self.index} {self.twin}:{self.scenario}:{what}"


@functools.lru_cache(maxsize=None)
def _spec(name: str) -> dict:
    return load_machine(name).to_dict()


def twin_spec(name: str) -> dict:
    return copy.deepcopy(_spec(name))


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def generic_programme(spec: dict, t: np.ndarray, rng: np.random.Generator) -> dict:
    """Inputs for any machine: speed and power inputs in random blocks of 1-4 h, switches
    (coolant, oil, door) on at random within running or standing blocks, temperature set
    points steady with steps, the hall on a day/night cycle with a door drop."""
    n = t.size
    hour = t / 3600.0
    running = np.zeros(n, dtype=bool)
    k, on = 0, bool(rng.random() < 0.5)
    while k < n:
        dur = max(1, int(np.searchsorted(t, t[k] + rng.uniform(1.0, 4.0) * 3600.0)) - k)
        running[k:k + dur] = on
        k, on = k + dur, not on
    out: dict[str, np.ndarray] = {}
    for name, d in spec["inputs"].items():
        lo, hi = float(d.get("min", 0.0)), float(d.get("max", 1.0))
        low, unit = name.lower(), str(d.get("unit", "")).lower()
        if d.get("kind") == "environment":
            base = float(d.get("default", 20.0)) + rng.uniform(-2.0, 2.0)
            amb = base + rng.uniform(0.5, 3.0) * np.sin(2 * math.pi * (hour - rng.uniform(6, 12)) / 24.0)
            drop_at = rng.uniform(0.2, 0.9) * t[-1]
            amb -= (t >= drop_at) * rng.uniform(0.0, 3.0) * np.exp(-np.clip(t - drop_at, 0, None) / 3600.0)
            out[name] = amb
        elif unit == "bool":
            blocks = np.repeat(rng.random(n // 12 + 2) < rng.uniform(0.3, 0.8), 12)[:n]
            out[name] = ((~running if "door" in low else running) & blocks).astype(float)
        elif "degc" in unit:
            steps = np.repeat(rng.uniform(-3.0, 3.0, n // 144 + 2), 144)[:n]
            out[name] = np.clip(float(d.get("default", 22.0)) + steps, lo, hi)
        else:
            levels = np.repeat(rng.choice([0.25, 0.5, 0.75, 1.0], n // 24 + 2), 24)[:n]
            out[name] = np.round(running * levels * hi * rng.uniform(0.5, 1.0), 0)
    return out


def case_timeline(case: RandomCase) -> InputsTimeline:
    if case.scenario != "programme":
        return make_timeline(case.twin, case.scenario, hours=case.hours,
                             seed=case.seed * 100_003 + case.index, step_s=case.step_s)
    t = np.arange(0.0, case.hours * 3600.0 + 0.5 * case.step_s, case.step_s)
    rng = np.random.default_rng([case.seed, case.index, 1])
    return InputsTimeline(t, generic_programme(_spec(case.twin), t, rng), name="programme")


def _channels(spec: dict) -> list[str]:
    m = load_machine(spec)
    return [m.sensors[s].column for s in m.sensors] + list(m.errors)


def candidates_by_type(spec: dict, tl: InputsTimeline) -> dict[str, list]:
    """The finder's candidates for this machine and programme, grouped by effect type."""
    drivers = {k: classify_driver(k, np.asarray(v, dtype=float)) for k, v in tl.values.items()}
    groups: dict[str, list] = {}
    for c in candidates(spec, drivers, _channels(spec)):
        groups.setdefault(c.effect, []).append(c)
    return groups


def _shape_values(c, rng: np.random.Generator) -> list[float]:
    """The candidate's values at unit amplitude (amplitude scaled later to the drawn size);
    shape parameters (exponent, coolant temperature, lag) drawn here."""
    names = [p.name for p in c.params]
    v = [1.0] + [0.0] * (len(names) - 1)
    if c.effect == "periodic_load":
        phase = rng.uniform(0, 2 * math.pi)
        v = [math.cos(phase), math.sin(phase)]
    for i, n in enumerate(names):
        if n == "exponent":
            v[i] = rng.uniform(0.8, 2.0)
        elif n.startswith("T_"):
            v[i] = rng.uniform(12.0, 30.0)
    if c.effect == "time_lag":
        v[0] = _log_uniform(rng, 600.0, 4 * 3600.0)
    if c.effect in ("sensor_bias", "elastic_gain") and rng.random() < 0.5:
        v[0] = -v[0]
    return v


def _draw_setup(seed: int, index: int, rng: np.random.Generator) -> dict:
    twin = str(rng.choice(preset_names()))
    scenarios = ["programme"] + [s for s in scenario_names(twin) if s != "fl-thermal-programme"]
    scenario = str(rng.choice(scenarios))
    hours = float(np.round(rng.uniform(*HOURS_RANGE), 1))
    step = float(rng.choice([60.0, 120.0, 300.0, 600.0]))
    step = max(step, math.ceil(hours * 3600.0 / MAX_ROWS / 60.0) * 60.0)
    colour = str(rng.choice(["white", "ar1", "random_walk"]))
    noise = {"colour": colour, "sigma_k": _log_uniform(rng, 0.005, 0.05),
             "sigma_um": _log_uniform(rng, 0.05, 0.5), "phi": float(rng.uniform(0.8, 0.98)),
             "quant_k": float(rng.choice([0.0, 0.01, 0.0625, 0.1])),
             "quant_um": float(rng.choice([0.0, 0.01, 0.1])),
             "drop_fraction": 0.0 if rng.random() < 0.4 else float(rng.uniform(0.005, 0.08)),
             "clock_offset_s": 0.0 if rng.random() < 0.6 else float(rng.uniform(-2.0, 2.0) * step)}
    return {"seed": seed, "index": index, "twin": twin, "scenario": scenario, "hours": hours,
            "step_s": step, "noise": noise}


def draw_case(seed: int, index: int) -> RandomCase:
    """Case ``index`` of ``seed``: drawn from its own generator, independent of other cases."""
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"seed: {seed!r} must be an integer >= 0")
    if not (isinstance(index, (int, np.integer)) and index >= 0):
        raise ValueError(f"index: {index!r} must be an integer >= 0")
    rng = np.random.default_rng([int(seed), int(index)])
    setup = _draw_setup(int(seed), int(index), rng)
    kind = str(rng.choice(KINDS, p=KIND_P))
    size = _log_uniform(rng, *SIZE_RANGE)
    onset = 0.0 if rng.random() < 0.7 else float(np.round(rng.uniform(0.05, 0.35) * setup["hours"], 2))
    base = RandomCase(kind=kind, size=size, onset_h=onset if kind in ("named", "two") else 0.0, **setup)
    spec = _spec(base.twin)
    if kind == "none":
        return dataclasses.replace(base, size=0.0)
    if kind == "unnamed":
        return dataclasses.replace(base, oov=(_draw_oov(spec, rng),))
    groups = candidates_by_type(spec, case_timeline(base))
    types = sorted(groups)
    picked = rng.choice(types, size=min(2 if kind == "two" else 1, len(types)), replace=False)
    hidden = []
    for ty in picked:
        c = groups[str(ty)][int(rng.integers(len(groups[str(ty)])))]
        hidden.append(HiddenEffect(c.effect, c.target, c.driver, tuple(_shape_values(c, rng))))
    return dataclasses.replace(base, hidden=tuple(hidden))


def _draw_oov(spec: dict, rng: np.random.Generator) -> Oov:
    kind = str(rng.choice(OOV_KINDS))
    sensors = [s for s, d in spec["sensors"].items() if isinstance(d.get("of"), str) and d["of"] in spec["nodes"]]
    if kind == "sensor_drift":
        return Oov(kind, str(rng.choice(sensors)), float(rng.choice([-1.0, 1.0])))
    if kind == "moved_sensor":
        s = str(rng.choice(sensors))
        other = [n for n in spec["nodes"] if n != spec["sensors"][s]["of"]]
        return Oov(kind, f"{s}->{rng.choice(other)}")
    pairs = [(ch, n) for ch, d in spec["errors"].items() for n in d.get("terms", {}) if n in spec["nodes"]]
    ch, node = pairs[int(rng.integers(len(pairs)))]
    return Oov(kind, f"{ch}/{node}", float(rng.choice([-1.0, 1.0])))
