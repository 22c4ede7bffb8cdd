"""The structural stage of ``learn``: after the bounded calibration, try words for what the unit
differs in (learn.words), each fitted on the fit window (training probes + temperatures), and
keep a word only if it is better on the validation probes it was not fitted to.

The fit: every channel the twin shares with the recording counts as one (its squared residual
summed over its rows in the fit window, divided by its row count and by what the calibrated twin
leaves there, floored at the probe noise or ``TEMP_FLOOR_K``), so a few probes weigh as much as
a temperature sampled every minute. The choice: open loop on the validation probes, the word's
noise-normalised SSE below ``WORD_MARGIN`` x the twin's without it and no component worse by
more than its probe uncertainty (learn.adoption.decide), and its effect on some error component
at least ``MIN_EFFECT`` probe uncertainties (RMS over the validation rows, where the prior takes
over: a smaller one cannot be told from the probe noise); of the words that pass, the one that
fits the fit window best (its many temperature rows and probes; the few validation probes only
guard) is added, then the search
runs once more on top of it (at most ``MAX_WORDS``). A boundary that follows and a sensor that
drifts (``JOINT_KINDS``) are fitted together with the strained couplings to the boundaries (the
conductances of links to a boundary, the speed-driven convection), each within its tolerance: the first
calibration, fitted without the word, has moved them to absorb part of it (a drifting hall
sensor into the hall couplings and the convection), and the word fitted on that twin alone comes
out too small. A final bounded calibration of the type's
twin with the words (started from the first calibration) lets the parameters that had absorbed
the missing physics go back; the words' own parameters move in their wide ranges. No rclpy.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from thermal_comp_common.recording_csv import Recording
from thermal_twin.calibrate.bounds import free_parameters, set_values
from thermal_twin.calibrate.fit import calibrate
from thermal_twin.diagnose.twin_eval import node_states, outputs_from_states
from thermal_twin.machine.schema import Machine, load_machine
from thermal_twin.physics.boundary_follow import follow_series, lowered, lower_spec
from thermal_twin.physics.sensor_model import drift_offsets
from thermal_twin.sim.inputs_timeline import timeline_from_recording

from thermal_eval.learn.adoption import Adoption, decide
from thermal_eval.learn.words import Word, candidates

#: a word must bring the validation probes' normalised SSE below this fraction of the twin's without it
WORD_MARGIN = 0.8
#: at most this many words are added to one unit
MAX_WORDS = 2
#: the smallest residual scale of a temperature channel [K] (its quantisation and lag)
TEMP_FLOOR_K = 0.05
#: a word must change some error component by at least this many probe uncertainties (RMS)
MIN_EFFECT = 1.0
#: optimiser evaluations per word fit
WORD_NFEV = 40
#: words fitted together with the strained parameters (module docstring): a boundary that
#: follows and a sensor that drifts change what a boundary does, and the first calibration has
#: absorbed part of that into the couplings to the boundaries without reaching their bounds
JOINT_KINDS = ("follows", "sensor_drift")
#: optimiser iterations of a joint fit (each costs one twin run per parameter for the Jacobian)
JOINT_NFEV = 20


def twin_outputs(spec: dict, rec: Recording, stop: int | None = None) -> dict[str, np.ndarray]:
    """Noise-free outputs of a description (following boundaries and drifts included) on the
    recording's rows, its inputs from the recording (a sensor-fed input read backwards)."""
    return twin_run(spec, rec, stop)[0]


def twin_run(spec: dict, rec: Recording, stop: int | None = None):
    """(outputs, node temperatures, node names) of :func:`twin_outputs`."""
    m = load_machine(spec)
    vals = timeline_from_recording(m, rec).resolved(m)
    vals.update(follow_series(m, rec.time_s, vals))
    low = lowered(m)
    net, t, X, tb = node_states(low, rec.time_s, vals, stop)
    out = outputs_from_states(low, net, t, X, tb)
    for c, d in drift_offsets(m, t).items():
        out[c] = out[c] + d
    return out, X, net.node_names


@dataclass
class Tried:
    word: Word
    theta: np.ndarray
    fit_cost: float
    validation: dict
    base: str = "calibrated"          # fitted on the calibrated twin or on it with bounded parameters set back
    chosen: bool = False
    gains: dict = field(default_factory=dict)   # the error gains refitted with the word
    moved: dict = field(default_factory=dict)   # strained parameters fitted with the word (name -> value)

    def spec_on(self, base: dict) -> dict:
        """``base`` with the word and the parameters fitted with it."""
        return self.word.spec(_with_values(base, self.moved), self.theta)

    def as_dict(self) -> dict:
        return {"word": self.word.label, "kind": self.word.kind, "what": self.word.describe(self.theta),
                "fitted_on": f"the {self.base} twin",
                "parameters": dict(zip(self.word.params, [float(v) for v in self.theta])),
                "moved_with_it": {k: float(v) for k, v in self.moved.items()},
                "fit_cost": round(self.fit_cost, 4), "validation": self.validation, "chosen": self.chosen}


class Scorer:
    """Residuals on the fit window and predictions at the validation probes of ``rec`` (the fit
    rows up to the end of the validation window, probe columns NaN off the probe rows). A
    subclass may score several runs: it gives :meth:`simulate` and calls :meth:`setup`."""

    def __init__(self, rec: Recording, channels: list[str], components: list[str], noise: dict,
                 fit_until: float, base: dict, type_spec: dict):
        self.rec, self.stop = rec, len(rec)
        self.setup(channels, components, noise, rec.time_s <= fit_until,
                   {c: np.asarray(rec.columns[c], float) for c in channels}, base, type_spec)

    def simulate(self, spec: dict):
        """(outputs, node temperatures, node names) of the description on the scored rows."""
        return twin_run(spec, self.rec, self.stop)

    def setup(self, channels: list[str], components: list[str], noise: dict, fit: np.ndarray, meas: dict,
              base: dict, type_spec: dict) -> None:
        """The rows (``fit``: fitted, the rest validation), the measurements and their weights."""
        self.channels, self.components, self.noise = channels, components, noise
        self.fit = fit
        self.val = ~self.fit
        self.meas = meas
        self.evals = 0
        self.type_gains = {c: dict(type_spec["errors"][c]["terms"]) for c in components}
        self.sd_fit = None                 # the gains' data weight: what the calibrated twin leaves
        self.gains: dict = {}
        out = self.outputs(base)
        self.sd_fit = {c: math.sqrt(max(float(np.nanmean((self.meas[c] - out[c])[self.fit] ** 2)), noise[c] ** 2))
                       for c in components}
        out = self.outputs(base)
        self.scale = {}
        for c in channels:
            ok = self.fit & np.isfinite(self.meas[c])
            mse = float(np.mean((self.meas[c][ok] - out[c][ok]) ** 2)) if ok.any() else 0.0
            floor = noise[c] if c in components else TEMP_FLOOR_K
            self.scale[c] = math.sqrt(max(ok.sum(), 1) * max(mse, floor ** 2))
        self.base_out = out

    def outputs(self, spec: dict) -> dict[str, np.ndarray]:
        """The description's outputs, its error gains refitted to the fit window's probes (a
        word changes the temperatures the gains map; the calibration tuned them to the old ones)."""
        self.evals += 1
        out, X, names = self.simulate(spec)
        if self.sd_fit is None:
            return out
        self.gains = {}
        for c in self.components:
            terms = spec["errors"][c]["terms"]
            nodes = list(terms)
            col = [names.index(n) for n in nodes]
            ok = self.fit & np.isfinite(self.meas[c])
            A = X[:, col] - X[0, col]
            g0 = np.array([self.type_gains[c].get(n, terms[n]) for n in nodes])
            sd = np.maximum(0.3 * np.abs(g0), 0.1) / 2.0          # the gain tolerance as a 95 % range
            w = 1.0 / self.sd_fit[c] ** 2
            g = np.linalg.solve(w * A[ok].T @ A[ok] + np.diag(1.0 / sd ** 2),
                                w * A[ok].T @ self.meas[c][ok] + g0 / sd ** 2)
            out[c] = float(spec["errors"][c].get("offset", 0.0)) + A @ g
            self.gains[c] = dict(zip(nodes, g.tolist()))
        return out

    def residual(self, out: dict) -> np.ndarray:
        parts = []
        for c in self.channels:
            ok = self.fit & np.isfinite(self.meas[c])
            parts.append((self.meas[c][ok] - out[c][ok]) / self.scale[c])
        return np.concatenate(parts)

    def validation(self, base_out: dict, out: dict, margin: float):
        ok = self.val & np.any([np.isfinite(self.meas[c]) for c in self.components], axis=0)
        vals = {c: self.meas[c][ok] for c in self.components}
        return decide(vals, self.noise, {c: base_out[c][ok] for c in self.components},
                      {c: out[c][ok] for c in self.components}, np.ones(int(ok.sum()), bool), margin=margin)


def _fit_word(scorer: Scorer, base: dict, word: Word, joint: list = ()) -> tuple[np.ndarray, float, dict, dict]:
    """(the word's theta, fit cost, outputs, the ``joint`` parameters' values fitted with it):
    the word alone, or together with ``joint`` (Params, each within its tolerance bounds, from
    its value in ``base``)."""
    k, joint = word.theta0.size, list(joint)
    x0 = np.concatenate([word.theta0, [p.theta(float(np.clip(_get(base, p.path), p.lo, p.hi))) for p in joint]])
    lb = np.concatenate([word.lb, [min(p.theta_bounds) for p in joint]])
    ub = np.concatenate([word.ub, [max(p.theta_bounds) for p in joint]])
    values = lambda x: {p.name: p.value(v) for p, v in zip(joint, x[k:])}      # noqa: E731
    byname = {p.name: p for p in joint}

    def spec(x):
        return word.spec(_with_values(base, values(x), byname), x[:k])

    def fun(x):
        return scorer.residual(scorer.outputs(spec(x)))
    try:
        sol = least_squares(fun, np.clip(x0, lb, ub), bounds=(lb, ub), method="trf", diff_step=1e-4,
                            max_nfev=JOINT_NFEV if joint else WORD_NFEV, x_scale=np.maximum(ub - lb, 1e-9) / 4.0)
        x = sol.x
    except (ValueError, np.linalg.LinAlgError):       # a word the twin cannot run (an invalid description)
        return word.theta0, math.inf, {}, {}
    out = scorer.outputs(spec(x))
    r = scorer.residual(out)
    return x[:k], float(r @ r), out, values(x)


def _get(spec: dict, path: tuple) -> float:
    d = spec
    for key in path:
        d = d[key]
    return float(d)


def _with_values(spec: dict, values: dict, params: dict | None = None) -> dict:
    """A copy of ``spec`` with parameter values by name (paths from ``params`` or the names)."""
    if not values:
        return spec
    out = copy.deepcopy(spec)
    for name, v in values.items():
        path = params[name].path if params else tuple(name.split("."))
        d = out
        for key in path[:-1]:
            d = d[key]
        d[path[-1]] = float(v)
    return out


@dataclass
class Structure:
    words: list[Tried] = field(default_factory=list)      # adopted, in order
    tried: list[Tried] = field(default_factory=list)
    spec: dict | None = None                               # the final description (None: no word)
    wall_s: float = 0.0
    evals: int = 0
    recalibration: str = ""                                # the final calibration against the words alone


def search(machine: Machine, cal_spec: dict, at_bound: list, rec: Recording, components: list[str],
           noise: dict, fit_until: float, progress: Callable[[str], None] = lambda m: None,
           make_scorer: Callable[[list[str], dict], Scorer] | None = None) -> Structure:
    """Words for the unit (module docstring): ``rec`` holds the fit rows up to the end of the
    validation window with the probes in their columns. Each word is fitted on two bases, the
    calibrated twin and the type's (where the calibration has not absorbed the missing physics
    into bounded parameters), and judged against the best description so far. ``make_scorer``
    (channels, base description -> Scorer): another scorer (several runs), ``rec`` then gives
    the channels and the inputs at the start only."""
    t0 = time.perf_counter()
    channels = [c for c in [s.column for s in machine.sensors.values()] + components if c in rec.columns]
    tl = timeline_from_recording(machine, rec)
    t0_inputs = {k: float(v[0]) for k, v in tl.values.items()}
    pool = candidates(machine, cal_spec, at_bound, t0_inputs)
    type_spec = machine.to_dict()
    bases = {"calibrated": copy.deepcopy(cal_spec)}
    released = released_names(at_bound)
    if released:
        bases["released"] = _set_back(cal_spec, machine.to_dict(), released)
    ref, st = bases["calibrated"], Structure()
    joint = coupling_parameters(machine, [p for p, _ in at_bound])
    for round_ in range(MAX_WORDS):
        scorer = Scorer(rec, channels, components, noise, fit_until, ref, type_spec) if make_scorer is None \
            else make_scorer(channels, ref)
        progress(f"structure: round {round_ + 1}, {len(pool)} candidate words on the calibrated and the type's twin")
        best = None
        for name, base in bases.items():
            for tried in _try_words(scorer, name, base, pool, joint, components, noise):
                st.tried.append(tried)
                if tried.validation.get("adopt") and (best is None or tried.fit_cost < best.fit_cost):
                    best = tried
        st.evals += scorer.evals
        if best is None:
            break
        best.chosen = True
        st.words.append(best)
        ref = _gains_into(best.spec_on(bases[best.base]), best.gains)
        bases = {k: _gains_into(best.spec_on(b), best.gains) for k, b in bases.items()}
        pool = [w for w in pool if w.label != best.word.label]
    if st.words:
        st.spec = ref
    st.wall_s = time.perf_counter() - t0
    return st


def coupling_parameters(machine: Machine, params: list) -> list:
    """Of ``params``, those that couple the machine to a boundary: the conductance of a link to
    a boundary and the speed-driven convection (the hall couplings a drifting hall sensor or a
    following chiller is absorbed into; the rest is the final calibration's)."""
    out = []
    for p in params:
        link = machine.links.get(p.path[1]) if p.path[0] == "links" else None
        if p.hi > p.lo and (p.kind == "convection" or (p.kind == "conductance" and link is not None and
                                                      (link.a in machine.boundaries or link.b in machine.boundaries))):
            out.append(p)
    return out


#: the reference of a word fitted jointly: the strained parameters refitted without a word
_NO_WORD = Word("none", "no word", (), np.zeros(0), np.zeros(0), np.zeros(0), lambda s, th: None, lambda th: "no word")


def _try_words(scorer: Scorer, name: str, base: dict, pool: list[Word], joint: list, components: list[str],
               noise: dict) -> list[Tried]:
    """Every word of ``pool`` fitted on ``base`` and judged: better on the fit window, not
    refused, an effect above the probe noise, then on the validation probes. A word fitted with
    the strained parameters is judged against those parameters refitted without it (what it
    adds, not what refitting them gives)."""
    out0 = scorer.outputs(base)
    r0 = scorer.residual(out0)
    cost0 = float(r0 @ r0)
    ref = {False: (cost0, out0)}
    if joint and any(w.kind in JOINT_KINDS for w in pool):
        _, cost_j, out_j, _ = _fit_word(scorer, base, _NO_WORD, joint)
        ref[True] = (cost_j, out_j) if out_j else ref[False]
    tried = []
    for w in pool:
        together = bool(joint) and w.kind in JOINT_KINDS
        theta, cost, out, moved = _fit_word(scorer, base, w, joint if together else ())
        if w.kind == "sensor_drift" and out:
            theta, cost, out = _drift_told(scorer, base, w, theta, moved, out, components, noise)
        c_ref, o_ref = ref[together]
        why = ("no better on the fit window" if not out or not cost < 0.95 * c_ref else
               w.refuse(theta) or _too_small(o_ref, out, components, noise, scorer.val))
        if why:
            tried.append(Tried(w, theta, cost / cost0, {"adopt": False, "validation_rmse": {}, "reason": why},
                               base=name, moved=moved))
            continue
        v = scorer.validation(scorer.base_out, out, WORD_MARGIN)
        if v.adopt and together:             # and better than the refit without it
            v_j = scorer.validation(o_ref, out, WORD_MARGIN)
            if not v_j.adopt:
                v = Adoption(False, f"against the strained parameters refitted without it: {v_j.reason}",
                             v_j.rmse, v_j.probes)
        tried.append(Tried(w, theta, cost / cost0, v.as_dict(), base=name, gains=copy.deepcopy(scorer.gains),
                           moved=moved))
    return tried


def _drift_told(scorer: Scorer, base: dict, word: Word, theta: np.ndarray, moved: dict, out: dict,
                components: list[str], noise: dict) -> tuple[np.ndarray, float, dict]:
    """A sensor's drift is kept only if the probes can tell it from none: its own effect on the
    errors (the word against the same word with no drift, on the validation rows) is at least
    ``MIN_EFFECT`` probe uncertainties; else it is written as 0. A drift extrapolates (its effect
    grows for as long as the prior runs), and a constant bias has none on the errors' changes
    (the twin starts in the steady state of its first reading), so the drift is the part to prove."""
    still = np.array(theta, float)
    still[list(word.params).index("drift_K_per_h")] = 0.0
    out0 = scorer.outputs(word.spec(_with_values(base, moved), still))
    if not _too_small(out0, out, components, noise, scorer.val):
        scorer.outputs(word.spec(_with_values(base, moved), theta))      # the word's refitted gains again
        return theta, _cost(scorer, out), out
    return still, _cost(scorer, out0), out0


def _cost(scorer: Scorer, out: dict) -> float:
    r = scorer.residual(out)
    return float(r @ r)


def _gains_into(spec: dict, gains: dict) -> dict:
    for c, terms in gains.items():
        spec["errors"][c]["terms"] = dict(terms)
    return spec


def _too_small(before: dict, after: dict, components: list[str], noise: dict, rows: np.ndarray) -> str:
    """A word whose effect on every error component stays below that component's probe
    uncertainty (RMS over ``rows``, the latest ones: where the prior takes over; a drift's
    effect grows with time and its mean since the start understates it) cannot be told from
    noise by probes: no word."""
    effect = max(float(np.sqrt(np.nanmean((after[c][rows] - before[c][rows]) ** 2))) / noise[c] for c in components)
    return "" if effect >= MIN_EFFECT else f"its effect on the errors is {effect:.2f} x the probe uncertainty at most"


def released_names(at_bound: list) -> list[str]:
    """The parameters the "released" base sets back: those that ended at their bound."""
    out = []
    for p, v in at_bound:
        lo, hi = p.lo, p.hi
        if hi > lo and min(abs(v - lo), abs(hi - v)) < 0.01 * (hi - lo):
            out.append(p)
    return out


def _set_back(spec: dict, type_spec: dict, params: list) -> dict:
    out = copy.deepcopy(spec)
    for p in params:
        d, t = out, type_spec
        for k in p.path[:-1]:
            d, t = d[k], t[k]
        d[p.path[-1]] = t.get(p.path[-1], 0.0)
    return out


def recalibrate(machine: Machine, st: Structure, cal, fit_rec: Recording, holdout: float, sigma: dict,
                max_nfev: int, released: list | None = None, progress: Callable[[str], None] = lambda m: None):
    """The final bounded calibration of the type's twin with the adopted words (module
    docstring): on the lowered description, the inputs given explicitly (a sensor-fed input read
    backwards through the words' bias and drift; that sensor's own column left out), started
    from the first calibration's values. Returns (description with the words, calibration)."""
    word_spec = machine.to_dict()
    for t in st.words:
        word_spec = t.word.spec(word_spec, t.theta)
    m = load_machine(word_spec)
    vals = timeline_from_recording(m, fit_rec).resolved(m)
    vals.update(follow_series(m, fit_rec.time_s, vals))
    fed = {s.from_sensor for s in m.inputs.values() if s.from_sensor}
    cols = {k: v for k, v in fit_rec.columns.items() if k not in {m.sensors[s].column for s in fed}}
    cols.update(vals)
    rec = Recording(fit_rec.time_s, cols, source=fit_rec.source)
    low = lower_spec(word_spec)
    section = copy.deepcopy(low.get("calibration") or {})
    params = section.setdefault("parameters", {})
    for t in st.words:
        params.update(t.word.release(t.theta))
    known = {p.name for p in free_parameters(low, section)}
    # from the first calibration's values, but those a word was fitted without (set back) from the type's
    back = {p.name for p in released or []} if any(t.base == "released" for t in st.words) else set()
    start = {e.param.name: e.value for e in cal.estimates
             if e.param.name in known and e.param.name not in params and e.param.name not in back}
    for t in st.words:                                    # the strained parameters fitted with a word
        start.update({n: v for n, v in t.moved.items() if n in known and n not in params})
    for c, terms in st.words[-1].gains.items():           # the gains refitted with the words
        start.update({f"errors.{c}.terms.{n}": g for n, g in terms.items() if f"errors.{c}.terms.{n}" in known})
    progress(f"recalibrating the twin with {', '.join(t.word.label for t in st.words)}")
    cal2 = calibrate(low, rec, holdout_fraction=holdout, section=section, max_nfev=max_nfev, start=start,
                     sigma=sigma)
    final = set_values(copy.deepcopy(word_spec), [e.param for e in cal2.estimates],
                       [e.value for e in cal2.estimates])
    return final, cal2
