"""The recording of a drawn case (:mod:`thermal_eval.diagnose.random_cases`) and its truth.

The true machine is the preset with the drawn effects applied (or a sensor moved) and its own
sensor noise and resolution switched off. An effect's amplitude parameter is scaled so the most
affected channel moves by ``case.size`` times that channel's noise RMS (one probe simulation at
unit amplitude; the effects are linear or nearly so in their amplitude), then halved until the
candidate's own plausibility check accepts it. The size actually reached is measured on the
noise-free outputs and returned (``size_measured``): a conduction between two nodes that stay
at one temperature stays undetectable whatever its conductance, and the score says so.
"""
from __future__ import annotations

import copy
import math

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_eval.diagnose.concealed import HiddenEffect
from thermal_eval.diagnose.random_cases import RandomCase, candidates_by_type, case_timeline, twin_spec
from thermal_twin.sim.simulate import simulate

ONSET_TAU_S = 3600.0


def _quiet(spec: dict) -> dict:
    spec = copy.deepcopy(spec)
    for d in spec["sensors"].values():
        d["noise_std"] = 0.0
        d["resolution"] = 0.0
    return spec


def _sigmas(spec: dict, cols: dict, noise: dict) -> dict[str, float]:
    sensor_cols = {d.get("column", f"{s}_c") for s, d in spec["sensors"].items()} | {f"{s}_c" for s in spec["sensors"]}
    return {c: (noise["sigma_k"] if c in sensor_cols else noise["sigma_um"]) for c in cols
            if c in sensor_cols or c in spec["errors"]}


def _size(cols: dict, base: dict, sig: dict) -> float:
    """Largest channel RMS change over its noise RMS."""
    return max((float(np.sqrt(np.mean((np.asarray(cols[c]) - base[c]) ** 2))) / s for c, s in sig.items()),
               default=0.0)


def _find(groups: dict, h: HiddenEffect):
    for c in groups.get(h.effect, []):
        if c.key == h.key:
            return c
    raise KeyError(f"no candidate {h.key!r}")


def _scaled_effect(spec: dict, tl, c, shape: tuple, size: float, base: dict, sig: dict) -> tuple[float, ...]:
    """The candidate's values with the amplitude set for ``size`` (a lag is not scaled)."""
    if c.effect == "time_lag":
        return tuple(shape)
    probe = np.asarray(shape, dtype=float)
    r = _size(simulate(c.apply(spec, probe), tl).columns(), base, sig)
    scale = size / r if r > 0 else 1.0
    amp = [0, 1] if c.effect == "periodic_load" else [0]
    for _ in range(40):
        v = probe.copy()
        v[amp] = probe[amp] * scale
        if c.implausible(v) is None:
            return tuple(float(x) for x in v)
        scale *= 0.5
    return tuple(float(x) for x in probe)


def _oov_term(case: RandomCase, spec: dict, res, cols: dict) -> tuple[str, np.ndarray]:
    o = case.oov[0]
    t = res.time_s
    if o.kind == "sensor_drift":
        return f"{o.target}_c", o.value * (t - t[0]) / 3600.0
    ch, node = o.target.split("/")
    rise = res.node_temperatures[:, list(res.machine.nodes).index(node)]
    rise = rise - rise[0]
    if o.kind == "quadratic_elastic":
        return ch, o.value * rise ** 2
    if o.kind == "product":
        drv = next(n for n, d in spec["inputs"].items() if d.get("kind") != "environment"
                   and str(d.get("unit", "")).lower() not in ("bool", "degc"))
        u = np.asarray(cols[drv], dtype=float)
        return ch, o.value * u / (np.max(np.abs(u)) or 1.0) * rise
    if o.kind == "hysteresis":   # play operator of half-width 10 % of the rise's range, minus the rise
        w = 0.1 * float(np.ptp(rise)) or 0.01
        y = np.empty_like(rise)
        y[0] = rise[0]
        for k in range(1, rise.size):
            y[k] = min(max(y[k - 1], rise[k] - w), rise[k] + w)
        return ch, o.value * (y - rise)
    raise ValueError(f"Oov.kind: {o.kind!r} has no additive term")


def _true_outputs(case: RandomCase, spec: dict, tl, base: dict, sig: dict) -> tuple[dict, list, dict]:
    """(noise-free recording columns of the true machine, hidden effects with final values, notes)."""
    notes: dict = {}
    hidden = []
    true = spec
    if case.hidden:
        groups = candidates_by_type(spec, tl)
        for h in case.hidden:
            c = _find(groups, h)
            v = _scaled_effect(spec, tl, c, h.values, case.size, base, sig)
            hidden.append(HiddenEffect(h.effect, h.target, h.driver, v))
            true = c.apply(true, np.asarray(v))
    if case.oov and case.oov[0].kind == "moved_sensor":
        s, node = case.oov[0].target.split("->")
        true = copy.deepcopy(true)
        true["sensors"][s]["of"] = node
    res = simulate(true, tl)
    cols = {k: np.asarray(v, dtype=float).copy() for k, v in res.columns().items()}
    if case.oov and case.oov[0].kind != "moved_sensor":
        ch, term = _oov_term(case, spec, res, cols)
        rms = float(np.sqrt(np.mean(term ** 2)))
        scale = case.size * sig[ch] / rms if rms > 0 else 0.0
        cols[ch] = cols[ch] + scale * term
        notes["oov_scale"] = scale * case.oov[0].value
    if case.onset_h > 0:
        t = res.time_s
        w = 1.0 - np.exp(-np.clip(t - t[0] - case.onset_h * 3600.0, 0.0, None) / ONSET_TAU_S)
        for c in sig:
            cols[c] = base[c] + w * (cols[c] - base[c])
    return cols, hidden, notes


def _noise(n: int, sigma: float, noise: dict, rng: np.random.Generator) -> np.ndarray:
    if noise["colour"] == "white":
        return sigma * rng.standard_normal(n)
    if noise["colour"] == "ar1":
        phi = noise["phi"]
        e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi ** 2)
        x = np.empty(n)
        x[0] = sigma * rng.standard_normal()
        for k in range(1, n):
            x[k] = phi * x[k - 1] + e[k]
        return x
    # random walk beside white noise: its steps make it about as large as the white part after 400 steps
    return sigma * rng.standard_normal(n) + np.cumsum(0.05 * sigma * rng.standard_normal(n))


def case_recording(case: RandomCase) -> tuple[Recording, dict]:
    """The case's recording and its truth: ``hidden`` (effects with their final values),
    ``oov`` keys, ``size_measured`` (largest channel change over noise RMS)."""
    spec = twin_spec(case.twin)
    tl = case_timeline(case)
    quiet = _quiet(spec)
    base = {k: np.asarray(v, dtype=float) for k, v in simulate(quiet, tl).columns().items()}
    sig = _sigmas(spec, base, case.noise)
    cols, hidden, notes = _true_outputs(case, quiet, tl, base, sig)
    size = _size(cols, base, sig)
    rng = np.random.default_rng([case.seed, case.index, 2])
    t = np.asarray(tl.time_s, dtype=float)
    nz = case.noise
    for c, s in sig.items():
        y = np.interp(t + nz["clock_offset_s"], t, cols[c]) if nz["clock_offset_s"] else cols[c]
        y = y + _noise(t.size, s, nz, rng)
        q = nz["quant_um"] if c in spec["errors"] else nz["quant_k"]
        cols[c] = np.round(y / q) * q if q > 0 else y
    keep = np.arange(t.size)
    if nz["drop_fraction"] > 0:
        keep = np.concatenate([[0], 1 + np.flatnonzero(rng.random(t.size - 1) >= nz["drop_fraction"])])
    rec = Recording(t[keep], {c: np.asarray(v)[keep] for c, v in cols.items()}, source=f"random:{case.label}")
    truth = {"hidden": hidden, "keys": [h.key for h in hidden] + [o.key for o in case.oov],
             "size_measured": size, **notes}
    return rec, truth
