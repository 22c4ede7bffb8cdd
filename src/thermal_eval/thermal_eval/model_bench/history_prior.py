"""``thermal-comp bench history-prior``: a prior from a machine's past runs against starting from zero and holding.

FL_THERMAL is cut into ``--segments`` runs of equal length, each with its own start reference
(errors and temperatures as deltas from its first row) and probing clock. For every run k >= 2
the runs before it are the machine's history: :func:`talc_model.prior.history.build_history_prior`
fits the prior of TALC, the AGP and the CD model on them (the last history run held out, as the
builders do), and run k is replayed row by row three ways, each model with its own logic
(:func:`thermal_eval.evaluate.model_rows.replay`): started from the history prior
(:func:`talc_model.prior.dispatch.model_from_prior`), started from zero, and holding the model's
own probes (0 before its first one: a run starts with nothing known). Figures per run and pooled
over the held-out runs: MAE and P99 (um, all channels), ratios to holding.
"""
from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np

from talc_model.adaptive_model import make_model
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.history import build_history_prior, component_name
from thermal_comp_common.metrics import mae, p99
from thermal_comp_common.recording_csv import read_recording_csv
from thermal_eval.evaluate.model_rows import hold_probes, replay
from thermal_eval.evaluate.spec import EvaluationData, make_split
from thermal_eval.fl_thermal.data import default_csv_path

KINDS = ("talc", "agp", "cd")
#: the runs' probing after the models' own start-up (calibration / prior check), h
PROBE_EVERY_H = 1.0
#: schedule keys per kind: one probing per PROBE_EVERY_H after the start-up
SCHEDULE = {"talc": {"post_cp_interval_h": PROBE_EVERY_H},
            "agp": {"control_interval_s": PROBE_EVERY_H * 3600.0, "min_calibration_s": 4 * 3600.0},
            "cd": {"update_probe_interval_s": PROBE_EVERY_H * 3600.0, "min_calibration_s": 4 * 3600.0}}


def segments(rec, n: int) -> list:
    """``rec`` cut into ``n`` runs of equal rows, each with its time from 0."""
    bounds = np.linspace(0, len(rec), n + 1).astype(int)
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        s = rec.slice(int(a), int(b))
        s.time_s = s.time_s - s.time_s[0]
        s.source = f"{rec.source or 'recording'} rows {a}-{b}"
        out.append(s)
    return out


def as_data(rec) -> EvaluationData:
    """A run as the replay sees it: sensors without ``_c``, components without ``_um``."""
    sensors = rec.names("sensor")
    inputs = rec.names("input")
    return EvaluationData(np.asarray(rec.time_s, float), np.column_stack([rec.columns[c] for c in sensors]),
                          [c[:-2] for c in sensors],
                          np.column_stack([rec.columns[c] for c in inputs]) if inputs else None, inputs,
                          {component_name(c): np.asarray(rec.columns[c], float) for c in rec.names("error")},
                          make_split(len(rec), {"train": 0.6, "validation": 0.2, "test": 0.2}), rec.source)


def _errors(data: EvaluationData, model) -> tuple[np.ndarray, np.ndarray, int]:
    rep = replay(data, model)
    res, held = [], []
    for ch in data.channels:
        y = data.displacement_um[ch] - data.displacement_um[ch][0]
        hold = np.nan_to_num(hold_probes(y, rep.probe_rows, len(data)), nan=0.0)
        res.append(y[1:] - rep.compensation[ch][1:])
        held.append(y[1:] - hold[1:])
    return np.concatenate(res), np.concatenate(held), len(rep.probe_rows)


def score_run(history: list, run, kind: str, na_max: int) -> dict[str, Any]:
    """The history prior of ``kind`` on ``run`` beside zero start and holding."""
    t0 = time.perf_counter()
    fit = {"na_max": na_max, "nb_max": 8} if kind == "talc" else {}
    prior = build_history_prior(kind, history, SCHEDULE[kind], **fit)
    data = as_data(run)
    out: dict[str, Any] = {"history_runs": len(history)}
    for name, model in (("prior", model_from_prior(kind, prior["run_config"], prior)),
                        ("zero", make_model(kind, prior["run_config"]))):
        res, held, probes = _errors(data, model)
        zero = np.zeros_like(res)
        out[name] = {"mae_um": round(mae(res, zero), 4), "p99_um": round(p99(res, zero), 4),
                     "hold_mae_um": round(mae(held, zero), 4), "hold_p99_um": round(p99(held, zero), 4),
                     "probes": probes, "holding_at_end": [c for c, d in model.hold.diagnostics().items()
                                                           if d["mode"] == "hold"]}
        out[name]["ratio_mae"] = round(out[name]["mae_um"] / out[name]["hold_mae_um"], 3)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    ap = argparse.ArgumentParser(prog="thermal-comp bench history-prior")
    ap.add_argument("--segments", type=int, default=6, help="runs FL_THERMAL is cut into (default %(default)s)")
    ap.add_argument("--models", default=",".join(KINDS), help="comma-separated subset of talc,agp,cd")
    ap.add_argument("--na-max", type=int, default=2, help="TALC prior: largest n_a (default %(default)s)")
    opts = ap.parse_args(getattr(args, "extra", []) or [])
    if opts.segments < 3:
        raise ValueError(f"--segments: {opts.segments} must be >= 3 (two history runs, one held out)")
    runs = segments(read_recording_csv(default_csv_path()), opts.segments)
    figures: dict[str, Any] = {"segments": opts.segments, "hours_per_run": round(float(runs[0].time_s[-1]) / 3600, 2)}
    print(f"FL_THERMAL in {opts.segments} runs of {figures['hours_per_run']} h; MAE um (ratio to holding its own probes)")
    for kind in [k for k in opts.models.split(",") if k]:
        per = {}
        for k in range(2, len(runs)):
            try:
                r = score_run(runs[:k], runs[k], kind, opts.na_max)
            except ValueError as exc:          # a prior that cannot be built or is refused
                r = {"error": str(exc)}
            per[f"run{k + 1}"] = r
            if "error" in r:
                print(f"  {kind:4s} run {k + 1}: {r['error']}", flush=True)
                continue
            print(f"  {kind:4s} run {k + 1} (history {k} runs): prior {r['prior']['mae_um']:.3f} "
                  f"({r['prior']['ratio_mae']:.2f})  zero {r['zero']['mae_um']:.3f} ({r['zero']['ratio_mae']:.2f})  "
                  f"hold {r['prior']['hold_mae_um']:.3f} / {r['zero']['hold_mae_um']:.3f}  "
                  f"P99 prior {r['prior']['p99_um']:.2f} zero {r['zero']['p99_um']:.2f}  {r['seconds']:.0f} s", flush=True)
        ok = [r for r in per.values() if "error" not in r]
        if ok:
            pooled = {w: round(float(np.mean([r[w]["mae_um"] for r in ok])), 4) for w in ("prior", "zero")}
            pooled["hold_prior_probes"] = round(float(np.mean([r["prior"]["hold_mae_um"] for r in ok])), 4)
            pooled["hold_zero_probes"] = round(float(np.mean([r["zero"]["hold_mae_um"] for r in ok])), 4)
            pooled["prior_over_zero"] = round(pooled["prior"] / pooled["zero"], 3) if pooled["zero"] > 0 else math.nan
            pooled["prior_over_hold"] = round(pooled["prior"] / pooled["hold_prior_probes"], 3)
            per["pooled_mean"] = pooled
            print(f"  {kind:4s} mean of {len(ok)} runs: prior {pooled['prior']:.3f}  zero {pooled['zero']:.3f}  "
                  f"hold {pooled['hold_prior_probes']:.3f}  prior/zero {pooled['prior_over_zero']:.2f}  "
                  f"prior/hold {pooled['prior_over_hold']:.2f}", flush=True)
        figures[kind] = per
    return figures
