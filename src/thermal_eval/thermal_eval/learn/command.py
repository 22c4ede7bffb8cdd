"""``thermal-comp learn``: from a cell's own recording to the unit's twin, a prior on it and a
report of what changed, scored on probes the fit never saw.

Steps: read the recording (temperatures, machine inputs, probing results + applied offsets;
never the ground-truth topic), calibrate the twin on the probes of the fit window (unit_fit),
write ``unit_twin.yaml``, decide on the validation probes whether it replaces the type's twin
(adoption), build the model's prior on an adopted twin (its soft sensors are the unit's twin:
``type_model`` = the file), and score the priors, the twins open loop and the baselines on the
held-out probes (probe_score). No rclpy.
"""
from __future__ import annotations

import json
import math
import pathlib
import time
from typing import Any, Callable

import numpy as np
import yaml

from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import load_prior, save_prior
from thermal_comp.prior.build import (build_prior, cached_prior, default_config, default_model_kind,
                                      training_scenarios)
from thermal_comp_common.recording_csv import Recording
from thermal_twin.machine.schema import Machine, load_machine

from thermal_eval.learn.adoption import ADAPTIVE_MARGIN, Adoption, decide
from thermal_eval.learn.probe_score import (hold_last, prequential_model, score_table, static_regression,
                                            training_mean)
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.learn.unit_fit import UnitFit, learn_unit_twin

UNIT_TWIN = "unit_twin.yaml"
UNIT_PRIOR = "prior.json"
UNIT_CONFIG = "model_config.yaml"


def _twin_at_probes(fit: UnitFit, probes: ProbeSet) -> tuple[dict, dict]:
    """The twin's open-loop error (deltas from the start) at the probe instants, before and after."""
    cal = fit.calibration
    idx = np.searchsorted(cal.time_s, probes.time_s)
    before = {c: np.asarray(cal.before[c], float)[idx] for c in fit.components}
    after = {c: np.asarray(cal.after[c], float)[idx] for c in fit.components}
    return before, after


def moved_parameters(fit: UnitFit) -> list[dict[str, Any]]:
    """Every fitted parameter, its start, value, change and whether it ended at its tolerance bound
    (evidence of physics beyond the builder's tolerance, not an answer)."""
    out = []
    for e in fit.calibration.estimates:
        d = e.as_dict()
        lo, hi = d["bounds"]
        span = hi - lo
        d["at_bound"] = bool(span > 0 and min(abs(d["value"] - lo), abs(hi - d["value"])) < 0.01 * span)
        out.append(d)
    return out


def write_unit_twin(fit: UnitFit, out: pathlib.Path, source: str) -> pathlib.Path:
    """The calibrated twin as a machine YAML (validated on the way back in)."""
    spec = dict(fit.spec)
    spec["description"] = (f"{fit.machine.description} -- learned from {source} "
                           f"(probes up to {fit.train_until_s / 3600.0:.1f} h)").strip()
    path = out / UNIT_TWIN
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    load_machine(str(path))
    return path


def _prior_models(machine: Machine, unit_path: pathlib.Path, out: pathlib.Path,
                  progress: Callable[[str], None], unit: bool = True) -> dict[str, tuple[dict, dict]]:
    """(config, prior) of the type's prior (nominal twin, from the cache) and, with ``unit``, of
    the unit's (built on its twin, written into ``out``)."""
    kind = default_model_kind(machine.name)
    scenarios = training_scenarios(kind, machine.name)
    if not scenarios:
        raise ValueError(f"--twin {machine.name!r}: no training programmes for a {kind} prior of this type")
    type_cfg = default_config(machine.name, kind)
    type_path, _ = cached_prior(machine.name, type_cfg, scenarios, kind=kind, progress=progress)
    models = {"type prior": (type_cfg, load_prior(type_path))}
    if unit:
        unit_cfg = default_config(str(unit_path), kind)
        progress(f"building the {kind} prior on the unit's twin ({len(scenarios)} programmes)")
        save_prior(out / UNIT_PRIOR, build_prior(str(unit_path), unit_cfg, scenarios, kind=kind, progress=progress))
        (out / UNIT_CONFIG).write_text(yaml.safe_dump(unit_cfg, sort_keys=False))
        models["unit prior"] = (unit_cfg, load_prior(out / UNIT_PRIOR))
    return models


def learn(twin, rec: Recording, probes: ProbeSet, out: pathlib.Path, train_h: float, max_nfev: int = 20,
          progress: Callable[[str], None] = lambda m: None, build_priors: bool = True,
          validate_h: float | None = None) -> dict[str, Any]:
    """Learn the unit (module docstring) and write its files into ``out``; the report as a dict.
    The twin is fitted on the probes up to ``train_h - validate_h`` (default a quarter of
    ``train_h``) and adopted only if it is better on the probes between (learn.adoption); the
    unit's prior is built only for an adopted twin. Probes after ``train_h`` are held out."""
    t0 = time.perf_counter()
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    validate_h = train_h / 4.0 if validate_h is None else float(validate_h)
    if not 0.0 <= validate_h < train_h:
        raise ValueError(f"--validate-h: {validate_h!r} must be >= 0 and below --train-h {train_h!r}")
    start = float(rec.time_s[0])
    fit_until, train_until = start + (train_h - validate_h) * 3600.0, start + train_h * 3600.0
    fit = learn_unit_twin(machine, rec, probes, fit_until, max_nfev=max_nfev, progress=progress)
    t_fit = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    unit_path = write_unit_twin(fit, out, rec.source or "a recording")
    sub = ProbeSet(probes.time_s, {c: probes.values[c] for c in fit.components},
                   {c: probes.noise[c] for c in fit.components}, probes.source)
    before, after = _twin_at_probes(fit, sub)
    validation = (sub.time_s > fit_until) & (sub.time_s <= train_until)
    adoption = decide(sub.values, sub.noise, before, after, validation)
    predictors = {"hold last probe": hold_last(sub), "training mean": training_mean(sub, train_until),
                  "static regression": static_regression(rec, sub, train_until),
                  "twin (type), open loop": before, "twin (unit), open loop": after}
    t1 = time.perf_counter()
    files = {"unit_twin": str(unit_path)}
    if build_priors:
        for name, (cfg, prior) in _prior_models(machine, unit_path, out, progress, adoption.adopt).items():
            progress(f"replaying the recording's probes with the {name}")
            model = model_from_prior(prior.get("model_kind", "talc"), cfg, prior)
            predictors[f"adaptive, {name}"] = prequential_model(model, rec, sub)
        adoption = _adaptive_check(adoption, sub, predictors, validation, out)
        if adoption.adopt:
            files |= {"prior": str(out / UNIT_PRIOR), "model_config": str(out / UNIT_CONFIG)}
    progress(("adopted: " if adoption.adopt else "not adopted: ") + adoption.reason)
    report = {"twin": machine.name, "recording": rec.source, "train_h": train_h, "validate_h": validate_h,
              "recording_h": float(rec.time_s[-1] - rec.time_s[0]) / 3600.0,
              "probes": {"train": fit.probes_train, "validation": adoption.probes,
                         "held_out": int((sub.time_s > train_until).sum()),
                         "noise": {c: sub.noise[c] for c in fit.components}, "notes": probes.notes},
              "adoption": adoption.as_dict(),
              "parameters": moved_parameters(fit), "fixed": fit.calibration.fixed,
              "held_out_scores": score_table(sub, predictors, sub.time_s > train_until),
              "files": files,
              "wall_s": {"calibration": round(t_fit, 1), "priors_and_scores": round(time.perf_counter() - t1, 1)},
              "twin_simulated_h_per_s": round(fit.calibration.simulated_h / max(fit.calibration.wall_s, 1e-9), 1)}
    (out / "report.json").write_text(json.dumps(_finite(report), indent=1, allow_nan=False) + "\n")
    return report


def _adaptive_check(open_loop: Adoption, sub: ProbeSet, predictors: dict, validation, out: pathlib.Path) -> Adoption:
    """An open-loop adoption stands only if the adaptive model from the unit's prior also beats
    the one from the type's prior on the validation probes (each predicted before it was seen);
    a prior that is not adopted is not left behind."""
    if not open_loop.adopt:
        return open_loop
    adaptive = decide(sub.values, sub.noise, predictors["adaptive, type prior"], predictors["adaptive, unit prior"],
                      validation, margin=ADAPTIVE_MARGIN)
    if adaptive.adopt:
        return Adoption(True, f"twin open loop {open_loop.reason}; adaptive model {adaptive.reason}",
                        open_loop.rmse, open_loop.probes)
    for name in (UNIT_PRIOR, UNIT_CONFIG):
        (out / name).unlink(missing_ok=True)
    return Adoption(False, f"the twin is better open loop, but the adaptive model from its prior is "
                           f"{adaptive.reason}", open_loop.rmse, open_loop.probes)


def _finite(v):
    """JSON without NaN: a figure that does not exist is null."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v
