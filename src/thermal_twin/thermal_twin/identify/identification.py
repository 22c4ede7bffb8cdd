"""Identify a lumped twin from a description and a recording (``thermal-comp twin init``).

The structure comes from :mod:`structure`; its conductances, capacities (all but the first
body's, which sets the scale: temperatures depend on ratios), source coefficients, switched
convection, thermo-elastic gains, sensor biases and constant boundary temperatures are fitted
with ``thermal-comp calibrate``'s machinery (:func:`thermal_twin.calibrate.fit.calibrate`:
bounded least squares on the simulated twin) within wide ranges (a factor 30, gains within 30 x
the channel's span per K, and within alpha x the structural loop's length when the description
gives it: no body's temperature can move an error by more than its whole loop expanding; without
that bound the fit of one day explained a slope by two hidden bodies with opposite gains tens of
um/K large, whose difference the twin then extrapolated), with calibrate's Gaussian prior toward the starting structure as a
weak regulariser (sd a quarter of those ranges; the data counted as their effective number of
samples): on one day of data the plain fit extrapolated worse (docs/twin_init.md). Two passes: the second weights every channel by the residual the first
left on it (maximum likelihood with one unknown variance per channel); temperature channels
are further down-weighted so that all of them together weigh as much as the sparse probes.

When the errors are sparse probes, the hidden bodies are chosen by Schwarz's information
criterion on the whole recording (but its last 5 %, calibrate's minimum): every structure with
0 ... ``hidden`` hidden bodies is fitted on it and the one with the smallest criterion on the
displacement channels is kept (:func:`information_criterion`), then fitted once more on the first
``1 - holdout`` only for the report's held-out figures. Why not a held-out window there: at the
end of one day it holds two or three probing instants, and it takes from the candidates the data
that show their slow part. When the errors are measured continuously the held-out window holds
thousands of their readings and is kept: hidden bodies are added one at a time while the held-out
score (the last ``holdout``, never fitted) falls by more than ``HIDDEN_MARGIN``, and the kept
structure is refitted on the whole recording (but its last 5 %). The measurements behind both
rules are in docs/twin_init.md. The notes say when the kept structure has a
mode slower than the data it was fitted on (``MODE_LIMIT`` x that length, :mod:`modes`): such a
mode shows in the data only as a slope, so its time constant and gains, and the twin's
extrapolation beyond the recording, are not identified. Refusing such structures was measured
and made the compensation worse (docs/twin_init.md), so it is reported, not enforced. No rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from thermal_comp_common.metrics import rmse
from thermal_comp_common.probe_and_hold import table_5_4_noise
from thermal_comp_common.recording_csv import Recording

from thermal_twin.calibrate.fit import CalibrationResult, calibrate
from thermal_twin.diagnose.fit import channel_sigma
from thermal_twin.identify.description import Description
from thermal_twin.identify.modes import slowest_mode_h
from thermal_twin.identify.structure import starting_spec

WIDE = 30.0                      # every positive parameter within a factor 30 of its start
SPARSE_FRACTION = 0.5            # a channel with fewer finite rows than this is sparse (probes)
PRIOR = True                     # calibrate's prior toward the start (module docstring)
FINAL_HOLDOUT = 0.05             # the final refit keeps only this much out (calibrate's minimum)
MODE_LIMIT = 1.0                 # a mode slower than this x the fitted data is not identified by it
HIDDEN_MARGIN = 0.01             # continuous errors: a hidden body must lower the held-out score by 1 %
CRITERION, HELD_OUT = "information criterion", "held-out score"   # how the hidden bodies were chosen


@dataclass
class Candidate:
    hidden: int
    spec: dict
    calibration: CalibrationResult
    holdout: dict[str, float]            # channel -> held-out RMSE
    score: float                         # mean held-out RMSE / training spread over the channels
    slowest_h: float = math.nan          # the fitted structure's slowest time constant at rest, h
    fitted_h: float = math.nan           # the length of data it was fitted on, h
    criterion: float = math.nan          # information criterion on the displacement channels


@dataclass
class Identification:
    description: Description
    spec: dict                           # the identified twin (refitted on the whole recording)
    chosen: Candidate                    # the kept structure fitted on the training part only
    candidates: list[Candidate]          # the structures tried (fitted as chosen_by needs)
    channels: list[str]
    n_train: int
    notes: list[str] = field(default_factory=list)
    chosen_by: str = CRITERION           # CRITERION or HELD_OUT


def error_offsets(d: Description, rec: Recording) -> dict[str, float]:
    """Each continuous displacement channel's first value within the first hour (the twin's
    errors are offset + deltas from the start); 0 for sparse probes (a cell's probes are errors
    since the start: one noisy probe is no offset) and when the first hour has none."""
    t = rec.time_s
    out = {}
    for ch in d.displacements:
        x = np.asarray(rec.columns[ch], float)
        first = np.flatnonzero(np.isfinite(x) & (t - t[0] <= 3600.0))
        sparse = np.isfinite(x).mean() < SPARSE_FRACTION
        out[ch] = float(x[first[0]]) if first.size and not sparse else 0.0
    return out


def channel_noise(d: Description, rec: Recording) -> dict[str, float]:
    """Measurement noise per displacement channel: sparse probes Table 5.4 (TALC thesis), a
    continuous channel from its second differences."""
    out = {}
    table = table_5_4_noise(list(d.displacements))
    for ch in d.displacements:
        x = np.asarray(rec.columns[ch], float)
        sparse = np.isfinite(x).mean() < SPARSE_FRACTION
        out[ch] = table[ch] if sparse else max(channel_sigma(x), 0.05)
    return out


def section(d: Description, spec: dict, rec: Recording) -> dict:
    """What the identification may move, and how far (module docstring)."""
    first = d.bodies[0]
    # a sensor that feeds a boundary (the hall, a coolant return) is the boundary: no bias of its own
    params: dict = {f"nodes.{first}.capacity": "fixed"}
    params |= {f"sensors.{sid}.bias": "fixed" for sid, p in d.sensors.items() if not p.body}
    physical = d.gain_bound()
    for ch, e in spec["errors"].items():
        x = np.asarray(rec.columns[ch], float)
        x = x[np.isfinite(x)]
        span = float(np.ptp(x)) if x.size else 1.0
        bound = WIDE * max(span, 0.1)
        bound = min(bound, physical) if physical > 0 else bound
        for node in e["terms"]:
            params[f"errors.{ch}.terms.{node}"] = {"bounds": [-bound, bound]}
    kinds = {k: {"factor": WIDE} for k in ("capacity", "conductance", "convection", "source")}
    kinds |= {"bias": {"absolute": 2.0}, "boundary": {"absolute": 5.0}}
    return {"kinds": kinds, "parameters": params}


def _spread(rec: Recording, c: str, n_train: int) -> float:
    x = np.asarray(rec.columns[c], float)[:n_train]
    x = x[np.isfinite(x)]
    return max(float(np.std(x)) if x.size > 1 else 1.0, 1e-3)


def _sigmas(cal: CalibrationResult | None, d: Description, rec: Recording, noise: dict[str, float]) -> dict:
    """Channel weights: first pass the measurement noise (temperatures at least 0.1 K), second
    pass the residual the first left (module docstring)."""
    temps = [c for c in (cal.channels if cal else []) if c not in d.displacements]
    if cal is None:
        return dict(noise)
    k = cal.n_train
    out = {c: max(rmse(cal.measured[c][:k], cal.after[c][:k]), noise.get(c, 0.0), 1e-3) for c in cal.channels}
    n_err = sum(int(np.isfinite(cal.measured[c][:k]).sum()) for c in d.displacements if c in cal.measured)
    n_tmp = sum(int(np.isfinite(cal.measured[c][:k]).sum()) for c in temps)
    if n_err and n_tmp > n_err:
        balance = math.sqrt(n_tmp / n_err)
        for c in temps:
            out[c] *= balance
    return out


def scored_channels(d: Description, channels: list[str]) -> list[str]:
    """The channels a structure is judged on: not the sensors that feed a boundary (the hall)."""
    feeding = {f"{sid}_c" for sid, p in d.sensors.items() if not p.body}
    return [c for c in channels if c not in feeding]


def fit_structure(d: Description, rec: Recording, hidden: int, holdout: float, max_nfev: int,
                  progress: Callable[[str], None], start: dict | None = None) -> Candidate:
    """Fit the structure with ``hidden`` hidden bodies on the first ``1 - holdout`` of ``rec``."""
    spec = starting_spec(d, rec, hidden)
    for ch, off in error_offsets(d, rec).items():
        spec["errors"][ch]["offset"] = off
    sec = section(d, spec, rec)
    noise = channel_noise(d, rec)
    cal = None
    values = dict(start or {})
    for k in range(2):
        cal = calibrate(spec, rec, holdout_fraction=holdout, section=sec, max_nfev=max_nfev, prior=PRIOR,
                        start=values, sigma=_sigmas(cal, d, rec, noise))
        values = {e.param.name: e.value for e in cal.estimates}
        progress(f"  {hidden} hidden: pass {k + 1} cost {cal.cost_before:.4g} -> {cal.cost_after:.4g} "
                 f"({cal.n_evals} twin runs, {cal.wall_s:.1f} s)")
    table = cal.channel_table()
    ho = {c: table[c]["holdout_rmse_after"] for c in scored_channels(d, cal.channels)}
    norm = [v / _spread(rec, c, cal.n_train) for c, v in ho.items() if math.isfinite(v)]
    score = float(np.mean(norm)) if norm else math.inf
    fitted_h = float(rec.time_s[min(cal.n_train, rec.time_s.size) - 1] - rec.time_s[0]) / 3600.0
    return Candidate(hidden, cal.spec, cal, ho, score, slowest_mode_h(cal.spec), fitted_h,
                     information_criterion(d, cal))


def information_criterion(d: Description, cal: CalibrationResult) -> float:
    """Schwarz's criterion of a fitted structure on its fitted rows, counted on the displacement
    channels' probes (what the twin is for): sum_c n_c ln(RSS_c / n_c) + k ln(sum_c n_c), k the
    fitted parameters and n_c the channel's fitted probes (some 25 min apart, each with its own
    noise). The temperatures are fitted but not counted: their thousands of autocorrelated rows
    would reward every added body. For probes only (:func:`probes_only`)."""
    k = cal.n_train
    log_lik, n_all = 0.0, 0
    for c in d.displacements:
        if c not in cal.measured:
            continue
        y, p = np.asarray(cal.scored(c), float)[:k], np.asarray(cal.after[c], float)[:k]
        r = (y - p)[np.isfinite(y) & np.isfinite(p)]
        if r.size < 2:
            continue
        log_lik += r.size * math.log(max(float(r @ r), 1e-12) / r.size)
        n_all += r.size
    if n_all == 0:
        return math.inf
    return log_lik + len(cal.estimates) * math.log(max(n_all, 2))


def identifiable(c: Candidate) -> bool:
    """No mode of the fitted structure slower than ``MODE_LIMIT`` x the data it was fitted on (module
    docstring)."""
    return c.slowest_h <= MODE_LIMIT * c.fitted_h


def probes_only(d: Description, rec: Recording) -> bool:
    """Whether every displacement channel of ``rec`` is sparse probes (module docstring)."""
    return all(np.isfinite(np.asarray(rec.columns[c], float)).mean() < SPARSE_FRACTION for c in d.displacements)


def identify(d: Description, rec: Recording, holdout: float = 0.25, max_nfev: int = 40,
             progress: Callable[[str], None] = lambda m: None) -> Identification:
    """Identify the twin (module docstring): hidden bodies by the information criterion on probes,
    by the held-out score on continuous displacement channels."""
    if probes_only(d, rec):
        return _by_criterion(d, rec, holdout, max_nfev, progress)
    return _by_holdout(d, rec, holdout, max_nfev, progress)


def _mode_note(best: Candidate) -> list[str]:
    if identifiable(best):
        return []
    return [f"the kept structure has a mode of {best.slowest_h:.1f} h, slower than the {best.fitted_h:.1f} h "
            "it was fitted on: its extrapolation beyond the recording is not identified by the data"]


def _by_criterion(d: Description, rec: Recording, holdout: float, max_nfev: int,
                  progress: Callable[[str], None]) -> Identification:
    """Every structure fitted on the whole recording, the smallest criterion kept, and fitted again
    on the training part for the held-out figures."""
    cands = []
    for hidden in range(d.hidden + 1):
        progress(f"fitting the structure with {hidden} hidden bod{'y' if hidden == 1 else 'ies'}")
        c = fit_structure(d, rec, hidden, FINAL_HOLDOUT, max_nfev, progress)
        cands.append(c)
        progress(f"  information criterion {c.criterion:.1f} ({len(c.calibration.estimates)} parameters), "
                 f"slowest mode {c.slowest_h:.1f} h on {c.fitted_h:.1f} h of data")
    best = min(cands, key=lambda c: c.criterion)
    progress(f"fitting {best.hidden} hidden on the first {100 * (1 - holdout):.0f} % for the held-out figures")
    # from the structure's own start: started from the whole-recording fit it would have seen the held-out rows
    trained = fit_structure(d, rec, best.hidden, holdout, max_nfev, progress)
    notes = [f"hidden bodies tried: {[c.hidden for c in cands]}, information criteria "
             f"{[round(c.criterion, 1) for c in cands]}, slowest modes {[round(c.slowest_h, 1) for c in cands]} h; "
             f"kept {best.hidden} (the smallest criterion: the errors are sparse probes)"]
    return Identification(d, best.spec, trained, cands, trained.calibration.channels, trained.calibration.n_train,
                          notes + _mode_note(best), CRITERION)


def _by_holdout(d: Description, rec: Recording, holdout: float, max_nfev: int,
                progress: Callable[[str], None]) -> Identification:
    """Hidden bodies added while the held-out score falls by ``HIDDEN_MARGIN``; the kept structure
    refitted on the whole recording."""
    cands = []
    best = None
    for hidden in range(d.hidden + 1):
        progress(f"fitting the structure with {hidden} hidden bod{'y' if hidden == 1 else 'ies'}")
        c = fit_structure(d, rec, hidden, holdout, max_nfev, progress)
        cands.append(c)
        progress(f"  held-out score {c.score:.4g}, slowest mode {c.slowest_h:.1f} h on {c.fitted_h:.1f} h of data")
        if best is None or c.score < best.score * (1.0 - HIDDEN_MARGIN):
            best = c
        else:
            break
    start = {e.param.name: e.value for e in best.calibration.estimates}
    progress(f"refitting {best.hidden} hidden on the whole recording")
    final = fit_structure(d, rec, best.hidden, FINAL_HOLDOUT, max_nfev, progress, start=start)
    notes = [f"hidden bodies tried: {[c.hidden for c in cands]}, held-out scores "
             f"{[round(c.score, 4) for c in cands]}, slowest modes {[round(c.slowest_h, 1) for c in cands]} h; "
             f"kept {best.hidden} (a hidden body must lower the score by {100 * HIDDEN_MARGIN:g} %: the errors "
             "are continuous)"]
    return Identification(d, final.spec, best, cands, best.calibration.channels, best.calibration.n_train,
                          notes + _mode_note(best), HELD_OUT)
