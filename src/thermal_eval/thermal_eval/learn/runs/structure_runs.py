"""learn's word search (learn.structure: a parameter beyond its tolerance, a boundary that
follows, an added source, a sensor bias and drift) on several runs: every run simulated alone
from its own start, its error gains refitted on the training probes of every run together,
every channel's residual over every run's fit rows counting as one, a word judged on the
validation probes (validation runs, or the end of every training run). The words are kept with
the joint calibration's parameters (the single-recording learn recalibrates with them; with
several runs that last fit is not made). No rclpy.
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from thermal_comp_common.recording_csv import Recording

from thermal_eval.learn.command import strained
from thermal_eval.learn.runs.fit import RunsFit
from thermal_eval.learn.runs.sources import CellRun
from thermal_eval.learn.structure import Scorer, Structure, search, twin_run
from thermal_eval.learn.unit_fit import fit_rows, probe_recording


class RunsScorer(Scorer):
    """:class:`~thermal_eval.learn.structure.Scorer` over runs laid end to end, each simulated
    alone (node temperatures as changes from its own start)."""

    def __init__(self, recs: Sequence[Recording], fit: Sequence[np.ndarray], channels: list[str],
                 components: list[str], noise: dict, base: dict, type_spec: dict):
        self.recs = list(recs)
        nan = lambda r: np.full(len(r), np.nan)       # noqa: E731
        meas = {c: np.concatenate([np.asarray(r.columns[c], float) if c in r.columns else nan(r) for r in self.recs])
                for c in channels}
        self.setup(channels, components, noise, np.concatenate(list(fit)), meas, base, type_spec)

    def simulate(self, spec: dict):
        outs, xs, names = [], [], []
        for rec in self.recs:
            out, X, names = twin_run(spec, rec)
            outs.append(out)
            xs.append(X - X[0])
        return {c: np.concatenate([o[c] for o in outs]) for c in outs[0]}, np.vstack(xs), names


def _scored(run: CellRun, components: list[str], until: float) -> tuple[Recording, np.ndarray]:
    """The run's rows (learn's row budget, every probe row) with its probes, and which are fitted."""
    full = probe_recording(run.rec, run.probes, components)
    rows = fit_rows(full, run.probes.time_s, until if math.isfinite(until) else float(full.time_s[-1]))
    rec = Recording(full.time_s[rows], {k: v[rows] for k, v in full.columns.items()}, source=run.rec.source)
    return rec, rec.time_s <= until


def runs_words(fit: RunsFit, runs: Sequence[CellRun], progress: Callable[[str], None] = lambda m: None
               ) -> tuple[Structure, dict | None]:
    """(the search, the unit's description with its words or None) on the fit's runs: the
    training runs (fitted up to their fit end) and the validation runs (never fitted)."""
    cal, comps = fit.calibration, fit.components
    order = sorted(set(fit.fit_until) | set(fit.validation))
    parts = [_scored(runs[i], comps, fit.fit_until.get(i, -math.inf)) for i in order]
    recs, masks = [p[0] for p in parts], [p[1] for p in parts]
    noise = {c: runs[0].probes.noise[c] for c in comps}
    type_spec = fit.machine.to_dict()
    make = lambda channels, ref: RunsScorer(recs, masks, channels, comps, noise, ref, type_spec)   # noqa: E731
    at = [(e.param, e.value) for e in cal.estimates if strained(e, fit.machine)]
    st = search(fit.machine, cal.spec, at, recs[0], comps, noise, math.inf, progress, make_scorer=make)
    return st, (st.spec if st.words else None)
