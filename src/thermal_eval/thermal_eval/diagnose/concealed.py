"""Recordings with a concealed effect: the proving ground of the mismatch finder.

:func:`operating_programme` draws a seeded, multi-regime programme for a machine (spindle
speed steps, coolant with the spindle, short door openings at standstill, day/night
ambient with a slow drift and a hall-door drop). :func:`concealed_recording` switches one
or more effects of :mod:`thermal_twin.diagnose.effects` on in the twin with known
parameters and simulates it with the twin's sensor noise and quantisation, so the finder
can be run against the unmodified twin and judged on what it recovers.

Harder, more realistic cases: :class:`OutOfVocabulary` physics that no word of the
vocabulary describes (a sensor's slow linear drift, a quadratic thermo-elastic term, a
speed x temperature product term) added to the simulated readings, coloured AR(1) sensor
noise on top of the twin's white noise, and rows dropped at random (a logger that missed
samples). :data:`SUITE` is the broadened case list of ``thermal-comp bench diagnose``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from thermal_twin.sim.inputs_timeline import InputsTimeline
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.effects import Candidate, candidates, classify_driver
from thermal_comp_common.recording_csv import Recording
from thermal_twin.sim.simulate import simulate


@dataclass(frozen=True)
class HiddenEffect:
    """An effect to switch on: the candidate key ``effect:target:driver`` and its values."""

    effect: str
    target: str
    driver: str | None
    values: tuple[float, ...]

    @property
    def key(self) -> str:
        return f"{self.effect}:{self.target}:{self.driver or '-'}"


@dataclass(frozen=True)
class OutOfVocabulary:
    """Physics outside the vocabulary, added to the simulated readings:
    ``sensor_drift`` (target: sensor id, value: K/h), ``quadratic_elastic`` (target:
    ``channel/node``, value: um/K^2 on the node's rise), ``product`` (target:
    ``channel/node``, value: um/K at full speed times the node's rise)."""

    kind: str
    target: str
    value: float

    @property
    def key(self) -> str:
        return f"unnamed:{self.kind}:{self.target}"


def _apply_oov(rec: Recording, res, o: OutOfVocabulary, spec: Mapping) -> None:
    t = rec.time_s
    if o.kind == "sensor_drift":
        rec.columns[f"{o.target}_c"] = rec.columns[f"{o.target}_c"] + o.value * (t - t[0]) / 3600.0
        return
    ch, node = o.target.split("/")
    rise = res.node_temperatures[:, list(res.machine.nodes).index(node)]
    rise = rise - rise[0]
    if o.kind == "quadratic_elastic":
        rec.columns[ch] = rec.columns[ch] + o.value * rise ** 2
    elif o.kind == "product":
        speed = next(n for n in spec["inputs"] if "rpm" in n.lower() or "speed" in n.lower())
        u = np.asarray(rec.columns[speed], dtype=float)
        rec.columns[ch] = rec.columns[ch] + o.value * u / (np.max(np.abs(u)) or 1.0) * rise
    else:
        raise ValueError(f"OutOfVocabulary.kind: {o.kind!r} is not sensor_drift, quadratic_elastic or product")


def _ar1(n: int, sigma: float, phi: float, rng: np.random.Generator) -> np.ndarray:
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi ** 2)
    x = np.empty(n)
    x[0] = rng.standard_normal() * sigma
    for k in range(1, n):
        x[k] = phi * x[k - 1] + e[k]
    return x


def operating_programme(spec: Mapping, hours: float, step_s: float, seed: int) -> InputsTimeline:
    """A seeded programme for the machine's inputs (names recognised by meaning: speed-like
    inputs, coolant, door, an environment input for the ambient temperature)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0 + 0.5 * step_s, step_s)
    n = t.size
    vals: dict[str, np.ndarray] = {}
    speed = np.zeros(n)
    k = 0
    running = False
    while k < n:
        dur = int(rng.uniform(1.0, 4.0) * 3600.0 / step_s)
        if running:
            speed[k:k + dur] = rng.choice([0.25, 0.5, 0.75, 1.0])
        k += max(dur, 1)
        running = not running
    for name, d in spec["inputs"].items():
        lname = name.lower()
        hi = float(d.get("max", 1.0))
        if d.get("kind") == "environment":
            hour = t / 3600.0
            vals[name] = (float(d.get("default", 20.0)) + 1.5 * np.sin(2 * math.pi * (hour - 9.0) / 24.0)
                          + 0.3 * np.sin(2 * math.pi * hour / (hours * 1.7) + rng.uniform(0, 6.28)))
            drop_at = rng.uniform(0.3, 0.8) * hours * 3600.0
            drop = (t >= drop_at) * (-2.5 * np.exp(-np.clip(t - drop_at, 0, None) / 3600.0))
            vals[name] = vals[name] + drop
        elif "rpm" in lname or "speed" in lname:
            vals[name] = np.round(speed * hi, 0)
        elif "coolant" in lname or "mwf" in lname or "oil" in lname:
            on = speed > 0
            blocks = np.repeat(rng.random(n // 20 + 1) < 0.6, 20)[:n]
            vals[name] = (on & blocks).astype(float)
        elif "door" in lname:
            door = np.zeros(n)
            idle = np.flatnonzero(speed == 0)
            if idle.size:
                for s in rng.choice(idle, size=min(idle.size, max(2, int(hours / 3))), replace=False):
                    door[s:s + int(rng.uniform(15, 45) * 60.0 / step_s) + 1] = 1.0
            vals[name] = np.where(speed == 0, door, 0.0)
    return InputsTimeline(t, vals, name=f"programme-seed{seed}")


def find_candidate(spec: Mapping, timeline: InputsTimeline, key: str) -> Candidate:
    """The library candidate with ``key`` for this machine and programme."""
    drivers = {k: classify_driver(k, v) for k, v in timeline.values.items()}
    m = load_machine(spec)
    chans = [m.sensors[s].column for s in m.sensors] + list(m.errors)
    for c in candidates(dict(spec), drivers, chans):
        if c.key == key:
            return c
    raise KeyError(f"no candidate {key!r} for machine '{spec.get('name')}'")


def concealed_recording(spec: Mapping, hidden: Sequence[HiddenEffect], hours: float = 48.0,
                        step_s: float = 300.0, seed: int = 0, oov: Sequence[OutOfVocabulary] = (),
                        ar1_sigma: float = 0.0, ar1_phi: float = 0.9,
                        drop_fraction: float = 0.0) -> tuple[Recording, dict]:
    """Simulate ``spec`` with ``hidden`` effects switched on; returns the recording (inputs,
    noisy quantised sensor readings, true errors plus probe noise) and the true machine.
    ``oov``: out-of-vocabulary physics added to the readings; ``ar1_sigma`` (K): coloured
    AR(1) noise (coefficient ``ar1_phi`` per step) added to every temperature reading;
    ``drop_fraction``: share of rows removed at random."""
    spec = dict(spec)
    tl = operating_programme(spec, hours, step_s, seed)
    true = spec
    for h in hidden:
        c = find_candidate(true, tl, h.key)
        true = c.apply(true, h.values)
    res = simulate(true, tl, seed=seed)
    rec = res.to_recording()
    rng = np.random.default_rng(seed + 10_000)
    for e in res.errors:   # displacement sensors: 0.1 um noise, 0.01 um resolution
        rec.columns[e] = np.round((rec.columns[e] + 0.1 * rng.standard_normal(len(rec))) / 0.01) * 0.01
    for o in oov:
        _apply_oov(rec, res, o, spec)
    if ar1_sigma > 0:
        for c in rec.names("sensor"):
            rec.columns[c] = rec.columns[c] + _ar1(len(rec), ar1_sigma, ar1_phi, rng)
    if drop_fraction > 0:
        keep = np.sort(np.concatenate([[0], 1 + np.flatnonzero(rng.random(len(rec) - 1) >= drop_fraction)]))
        rec = Recording(rec.time_s[keep], {c: np.asarray(v)[keep] for c, v in rec.columns.items()},
                        source=rec.source, warnings=list(rec.warnings))
    label = "+".join([h.key for h in hidden] + [o.key for o in oov]) or "none"
    rec.source = f"concealed:{label}:seed{seed}"
    return rec, true
