"""``thermal-comp bench hold-fallback``: every adaptive model with its own logic against holding its own probes.

TALC, the AGP and the CD model (``talc_model``), each started from zero with its own calibration,
probing and update logic, replay a recording row by row (the virtual experiment of
:func:`thermal_eval.evaluate.model_rows.replay`); beside each is holding the model's own probes
at the same instants. With and without the model's hold fall-back
(:mod:`talc_model.probing.hold_fallback`). Recordings:

- ``fl_thermal``: FL_THERMAL (46 h, 16 temperatures, 5 channels);
- ``quantised``: a synthetic temperature-driven error quantised in 0.13-um steps with slow
  plateaus (:func:`quantised_recording`, seeds given by ``--seeds``);

Figures per recording, model and fall-back setting: MAE and P99 (um, pooled over the channels)
of the compensated error and of holding, their ratio, the components in hold mode at the end and
what the model said about the signal. Rows: after the model's first probe. Errors are deltas from
the recording's first row (as the models see them). ``--quick``: every 4th FL_THERMAL row.
"""
from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np

from talc_model.adaptive_model import make_model
from thermal_comp_common.metrics import mae, p99
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.model_rows import agp_config, hold_probes, replay, talc_config
from thermal_eval.evaluate.spec import FL_THERMAL_SPEC, EvaluationData, load_evaluation_data, make_split
from thermal_eval.fl_thermal.data import default_csv_path

MODELS = ("talc", "agp", "cd")
#: the quantised recording's step (um), like a motorised spindle's axial-growth channel
QUANTUM_UM = 0.13


def cd_config(data: EvaluationData, budget: ProbingBudget) -> dict[str, Any]:
    """The CD model on TALC's medoid sensors (fit time grows fast with inputs), a 4-h calibration
    every 30 min, then a probing at the user's schedule."""
    return {"components": list(data.channels), "sensors": list(talc_config(data, budget)["input_names"]),
            "min_calibration_s": 4 * 3600.0, "calibration_probe_interval_s": 1800.0,
            "update_probe_interval_s": budget.probe_every_h * 3600.0, "probe_duration_s": budget.probe_duration_s}


CONFIGS = {"talc": talc_config, "agp": agp_config, "cd": cd_config}


def quantised_recording(seed: int, hours: float = 72.0, step_s: float = 60.0) -> EvaluationData:
    """Four temperatures (a hall random walk plus a daily cycle, three lagged structure nodes) and
    one error channel: a first-order lag (3 h) of a weighted temperature sum, quantised in
    QUANTUM_UM steps; the slow drift holds each step for hours (plateaus)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, step_s)
    hall = 20.0 + np.cumsum(rng.normal(0.0, 0.004, t.size)) + rng.uniform(0.3, 1.0) * np.sin(
        2 * np.pi * t / 86400.0 + rng.uniform(0, 2 * np.pi))
    temps = [hall]
    for tau_h in (1.0, 4.0, 12.0):
        a = math.exp(-step_s / (tau_h * 3600.0))
        x = np.empty_like(hall)
        x[0] = hall[0]
        for k in range(1, t.size):
            x[k] = a * x[k - 1] + (1 - a) * hall[k]
        temps.append(x + rng.normal(0.0, 0.01, t.size))
    temps = np.column_stack(temps)
    drive = (temps - temps[0]) @ rng.uniform(0.2, 0.8, temps.shape[1])
    a = math.exp(-step_s / (3 * 3600.0))
    e = np.zeros(t.size)
    for k in range(1, t.size):
        e[k] = a * e[k - 1] + (1 - a) * drive[k]
    y = QUANTUM_UM * np.round(e / QUANTUM_UM)
    return EvaluationData(t, temps, [f"T{i}" for i in range(temps.shape[1])], None, [], {"axial_um": y},
                          make_split(t.size, {"train": 0.6, "validation": 0.2, "test": 0.2}),
                          f"quantised seed {seed}")


def score(data: EvaluationData, kind: str, budget: ProbingBudget, fallback: bool) -> dict[str, Any]:
    """One model with its own logic on ``data``: MAE / P99 of it and of holding its probes."""
    cfg = {**CONFIGS[kind](data, budget), "hold_fallback": fallback}
    t0 = time.perf_counter()
    model = make_model(kind, cfg)
    rep = replay(data, model)
    if not rep.probe_rows:
        return {"error": "the model never probed"}
    rows = slice(rep.probe_rows[0] + 1, len(data))
    res, held = [], []
    for ch in data.channels:
        y = np.asarray(data.displacement_um[ch], float)
        y = y - y[np.isfinite(y)][0]
        hold = hold_probes(y, rep.probe_rows, len(data))
        res.append(y[rows] - rep.compensation[ch][rows])
        held.append(y[rows] - hold[rows])
    res, held = np.concatenate(res), np.concatenate(held)
    zero = np.zeros_like(res)
    diag = model.hold.diagnostics()
    out = {"mae_um": round(mae(res, zero), 4), "p99_um": round(p99(res, zero), 4),
           "hold_mae_um": round(mae(held, zero), 4), "hold_p99_um": round(p99(held, zero), 4),
           "probes": len(rep.probe_rows), "seconds": round(time.perf_counter() - t0, 1),
           "holding_at_end": [c for c, d in diag.items() if d["mode"] == "hold"],
           "signal": {c: d["signal"] for c, d in diag.items() if d["signal"]}}
    out["ratio_mae"] = round(out["mae_um"] / out["hold_mae_um"], 3) if out["hold_mae_um"] > 0 else math.nan
    out["ratio_p99"] = round(out["p99_um"] / out["hold_p99_um"], 3) if out["hold_p99_um"] > 0 else math.nan
    return out


def _print(name: str, kind: str, fallback: bool, r: dict) -> None:
    if "error" in r:
        print(f"  {name:14s} {kind:5s} fall-back {'on ' if fallback else 'off'}  {r['error']}", flush=True)
        return
    print(f"  {name:14s} {kind:5s} fall-back {'on ' if fallback else 'off'}  MAE {r['mae_um']:.3f} / hold "
          f"{r['hold_mae_um']:.3f} = {r['ratio_mae']:.2f}   P99 {r['p99_um']:.3f} / {r['hold_p99_um']:.3f} = "
          f"{r['ratio_p99']:.2f}   {r['probes']} probes, holding {r['holding_at_end'] or '-'}  {r['seconds']:.0f} s"
          + (f"  [{'; '.join(f'{c}: {w}' for c, w in r['signal'].items())}]" if r["signal"] else ""), flush=True)


def run(args: argparse.Namespace) -> dict[str, Any]:
    ap = argparse.ArgumentParser(prog="thermal-comp bench hold-fallback")
    ap.add_argument("--models", default=",".join(MODELS), help="comma-separated subset of talc,agp,cd")
    ap.add_argument("--seeds", default="11,12", help="seeds of the quantised recordings")
    ap.add_argument("--sections", default="fl_thermal,quantised", help="fl_thermal and/or quantised")
    ap.add_argument("--probe-every-h", type=float, default=1.0, help="the models' probing interval after calibration")
    opts = ap.parse_args(getattr(args, "extra", []) or [])
    kinds = [k for k in opts.models.split(",") if k]
    bad = sorted(set(kinds) - set(MODELS))
    if bad:
        raise ValueError(f"--models: {bad} not among {list(MODELS)}")
    budget = ProbingBudget(probe_every_h=opts.probe_every_h)   # no cap: the models probe as they decide
    recordings: list[tuple[str, EvaluationData]] = []
    sections = set(opts.sections.split(","))
    if "fl_thermal" in sections:
        data = load_evaluation_data(default_csv_path(), FL_THERMAL_SPEC)
        if getattr(args, "quick", False):
            idx = np.arange(0, len(data), 4)
            data = EvaluationData(data.time_s[idx], data.temperatures[idx], data.sensors, data.inputs[idx],
                                  data.input_names, {k: v[idx] for k, v in data.displacement_um.items()},
                                  make_split(idx.size, FL_THERMAL_SPEC["split"]), data.source)
        recordings.append(("fl_thermal", data))
    if "quantised" in sections:
        recordings += [(f"quantised_{s}", quantised_recording(int(s))) for s in opts.seeds.split(",") if s]
    figures: dict[str, Any] = {"probe_every_h": opts.probe_every_h}
    print("model with its own logic / holding its own probes (rows after its first probe, pooled channels)")
    for name, data in recordings:
        for kind in kinds:
            for fallback in (True, False):
                r = score(data, kind, budget, fallback)
                figures.setdefault(name, {}).setdefault(kind, {})["fallback_on" if fallback else "fallback_off"] = r
                _print(name, kind, fallback, r)
    on = [v["fallback_on"]["ratio_mae"] for rec in figures.values() if isinstance(rec, dict)
          for v in rec.values() if "ratio_mae" in v.get("fallback_on", {})]
    figures["worst_ratio_mae_fallback_on"] = max(on) if on else math.nan
    return figures
