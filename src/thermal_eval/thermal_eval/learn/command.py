"""``thermal-comp learn``: from a cell's own recording to the unit's twin, a prior on it and a
report of what changed, scored on probes the fit never saw.

Steps: read the recording (temperatures, machine inputs, probing results + applied offsets;
never the ground-truth topic), calibrate the twin on the probes of the fit window (unit_fit),
try words for what the calibration cannot say and keep those better on the validation probes
(structure: a parameter beyond its tolerance, a boundary that follows the hall, an added
source, a sensor bias and drift), write ``unit_twin.yaml``, decide on the validation probes whether it replaces the type's twin
(adoption), build the model's prior on an adopted twin (its soft sensors are the unit's twin:
``type_model`` = the file), and score the priors, the twins open loop and the baselines on the
held-out probes (probe_score). No rclpy.
"""
from __future__ import annotations

import json
import pathlib
import time
from typing import Any, Callable

import numpy as np
import yaml

from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import load_prior, save_prior
from thermal_comp.prior.build import (build_prior, cached_prior, default_config, default_model_kind,
                                      training_scenarios)
from thermal_comp_common.json_figures import finite_figures
from thermal_comp_common.recording_csv import Recording
from thermal_twin.identify.own_config import own_model_config, unit_config
from thermal_twin.machine.schema import Machine, load_machine

from thermal_eval.learn.adoption import ADAPTIVE_MARGIN, Adoption, decide
from thermal_eval.learn.current import CurrentPrior, type_current
from thermal_eval.learn.finder import located
from thermal_eval.learn.probe_score import (hold_last, prequential_model, score_table, static_regression,
                                            training_mean)
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.learn.structure import Structure, recalibrate, released_names, search, twin_outputs
from thermal_eval.learn.unit_fit import UnitFit, learn_unit_twin

UNIT_TWIN = "unit_twin.yaml"
UNIT_PRIOR = "prior.json"
UNIT_CONFIG = "model_config.yaml"


def _twin_at_probes(fit: UnitFit, probes: ProbeSet, unit_spec: dict | None = None) -> tuple[dict, dict]:
    """The twin's open-loop error (deltas from the start) at the probe instants, before and after
    (after: of ``unit_spec`` when the structural stage gave one)."""
    cal = fit.calibration
    idx = np.searchsorted(cal.time_s, probes.time_s)
    before = {c: np.asarray(cal.before[c], float)[idx] for c in fit.components}
    after_all = cal.after if unit_spec is None else twin_outputs(unit_spec, fit.fit_rec)
    after = {c: np.asarray(after_all[c], float)[idx] for c in fit.components}
    return before, after


def _at_bound(d: dict) -> bool:
    lo, hi = d["bounds"]
    span = hi - lo
    return bool(span > 0 and min(abs(d["value"] - lo), abs(hi - d["value"])) < 0.01 * span)


def moved_parameters(calibration) -> list[dict[str, Any]]:
    """Every fitted parameter, its start, value, change and whether it ended at its tolerance bound
    (evidence of physics beyond the builder's tolerance, not an answer)."""
    out = []
    for e in calibration.estimates:
        d = e.as_dict()
        d["at_bound"] = _at_bound(d)
        out.append(d)
    return out


def strained(e, machine: Machine) -> bool:
    """A parameter that may hide physics beyond the builder's tolerance: at its bound, moved by
    more than half its tolerance, or the conductance of a link to a boundary (the hall, a
    coolant: the convection coefficients scatter most)."""
    p, d = e.param, e.as_dict()
    if _at_bound(d) or abs(e.value - p.value0) > 0.5 * (p.hi - p.lo) / 2.0:
        return True
    link = machine.links.get(p.path[1]) if p.kind == "conductance" else None
    return link is not None and (link.a in machine.boundaries or link.b in machine.boundaries)


def _structure(fit: UnitFit, probes: ProbeSet, fit_until: float, train_until: float, max_nfev: int,
               progress) -> tuple[Structure, dict | None, Any]:
    """The structural stage (learn.structure) on the calibrated twin; (search, the unit's
    description with its words or None, the calibration its parameters come from or None). The
    final calibration with the words stands unless the validation probes find it worse than the
    words fitted without it (then the first calibration, or none for words on the type's twin)."""
    cal = fit.calibration
    at_strain = [(e.param, e.value) for e in cal.estimates if strained(e, fit.machine)]
    rec = fit.fit_rec
    upto = rec.slice(0, int(np.searchsorted(rec.time_s, train_until, side="right")))
    noise = {c: probes.noise[c] for c in fit.components}
    st = search(fit.machine, cal.spec, at_strain, upto, fit.components, noise, fit_until, progress)
    if not st.words:
        return st, None, None
    spec, cal2 = recalibrate(fit.machine, st, cal, rec, fit.holdout, noise, max_nfev, released_names(at_strain),
                             progress)
    val = (upto.time_s > fit_until) & np.any([np.isfinite(upto.columns[c]) for c in fit.components], axis=0)
    a, b = twin_outputs(st.spec, upto), twin_outputs(spec, upto)
    check = decide({c: upto.columns[c][val] for c in fit.components}, noise, {c: a[c][val] for c in fit.components},
                   {c: b[c][val] for c in fit.components}, np.ones(int(val.sum()), bool), margin=1.0 + 1e-9)
    st.recalibration = check.reason
    if check.adopt or not check.reason.startswith("worse"):
        return st, spec, cal2
    return st, st.spec, (cal if all(t.base == "calibrated" for t in st.words) else None)   # set back: not that calibration


def write_unit_twin(fit: UnitFit, out: pathlib.Path, source: str, spec: dict | None = None) -> pathlib.Path:
    """The calibrated twin (with its words when given ``spec``) as a machine YAML (validated on
    the way back in)."""
    spec = dict(fit.spec if spec is None else spec)
    spec["description"] = (f"{fit.machine.description} -- learned from {source} "
                           f"(probes up to {fit.train_until_s / 3600.0:.1f} h)").strip()
    path = out / UNIT_TWIN
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    load_machine(str(path))
    return path


def _prior_models(machine: Machine, unit_path: pathlib.Path, out: pathlib.Path,
                  progress: Callable[[str], None], unit: bool = True,
                  current: CurrentPrior | None = None) -> tuple[CurrentPrior, dict[str, tuple[dict, dict]]]:
    """(the prior tested against, name -> (config, prior)): ``current`` (``--current-prior``) or
    else the type's prior (nominal twin, from the cache) and, with ``unit``, the unit's (built on
    its twin, written into ``out``)."""
    kind = default_model_kind(machine.name)
    scenarios = training_scenarios(kind, machine.name)
    if not scenarios:
        raise ValueError(f"--twin {machine.name!r}: no training programmes for a {kind} prior of this type")
    # a twin file with its own configuration beside it (twin init's folder) is its own type: its
    # prior, never the cached prior of a preset that shares its name
    own = own_model_config(getattr(machine, "source_path", None))
    twin = str(machine.source_path) if own is not None else machine.name
    if current is None:
        type_cfg = default_config(twin, kind)
        type_path, _ = cached_prior(twin, type_cfg, scenarios, kind=kind, progress=progress)
        current = type_current(type_path, type_cfg)
    models = {reference_name(current): (current.config, current.prior)}
    if unit:
        unit_cfg = unit_config(own, unit_path) if own is not None else default_config(str(unit_path), kind)
        progress(f"building the {kind} prior on the unit's twin ({len(scenarios)} programmes)")
        save_prior(out / UNIT_PRIOR, build_prior(str(unit_path), unit_cfg, scenarios, kind=kind, progress=progress))
        (out / UNIT_CONFIG).write_text(yaml.safe_dump(unit_cfg, sort_keys=False))
        models["unit prior"] = (unit_cfg, load_prior(out / UNIT_PRIOR))
    return current, models


def reference_name(current: CurrentPrior) -> str:
    """The predictor name of the prior the learned one is tested against."""
    return "type prior" if current.source == "type" else "current prior"


def learn(twin, rec: Recording, probes: ProbeSet, out: pathlib.Path, train_h: float, max_nfev: int = 20,
          progress: Callable[[str], None] = lambda m: None, build_priors: bool = True,
          validate_h: float | None = None, current: CurrentPrior | None = None) -> dict[str, Any]:
    """Learn the unit (module docstring) and write its files into ``out``; the report as a dict.
    The twin is fitted on the probes up to ``train_h - validate_h`` (default a quarter of
    ``train_h``) and adopted only if it is better on the probes between (learn.adoption); the
    unit's prior is built only for an adopted twin. Probes after ``train_h`` are held out. The
    adaptive test is against ``current`` (learn.current; None: the type's prior)."""
    t0 = time.perf_counter()
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    validate_h = train_h / 4.0 if validate_h is None else float(validate_h)
    if not 0.0 <= validate_h < train_h:
        raise ValueError(f"--validate-h: {validate_h!r} must be >= 0 and below --train-h {train_h!r}")
    start = float(rec.time_s[0])
    fit_until, train_until = start + (train_h - validate_h) * 3600.0, start + train_h * 3600.0
    fit = learn_unit_twin(machine, rec, probes, fit_until, max_nfev=max_nfev, progress=progress)
    t_fit = time.perf_counter() - t0
    st, unit_spec, final_cal = _structure(fit, probes, fit_until, train_until, max_nfev, progress)
    final_cal = fit.calibration if not st.words else final_cal
    t_struct = time.perf_counter() - t0 - t_fit
    out.mkdir(parents=True, exist_ok=True)
    unit_path = write_unit_twin(fit, out, rec.source or "a recording", unit_spec)
    sub = ProbeSet(probes.time_s, {c: probes.values[c] for c in fit.components},
                   {c: probes.noise[c] for c in fit.components}, probes.source)
    before, after = _twin_at_probes(fit, sub, unit_spec)
    finder = located(machine, {"the twin it started from": fit.calibration.before, "the learned twin":
                               fit.calibration.after if unit_spec is None else twin_outputs(unit_spec, fit.fit_rec)},
                     fit.fit_rec, fit.components, fit_until)
    validation = (sub.time_s > fit_until) & (sub.time_s <= train_until)
    adoption = decide(sub.values, sub.noise, before, after, validation)
    predictors = {"hold last probe": hold_last(sub), "training mean": training_mean(sub, train_until),
                  "static regression": static_regression(rec, sub, train_until),
                  "twin (type), open loop": before, "twin (unit), open loop": after}
    t1 = time.perf_counter()
    files = {"unit_twin": str(unit_path)}
    tested_against = None
    if build_priors:
        current, priors = _prior_models(machine, unit_path, out, progress, adoption.adopt, current)
        tested_against, components = current.as_dict(), {}
        for name, (cfg, prior) in priors.items():
            progress(f"replaying the recording's probes with the {name}")
            model = model_from_prior(prior.get("model_kind", "talc"), cfg, prior)
            components[name] = list(model.component_names)
            predictors[f"adaptive, {name}"] = prequential_model(model, rec, sub)
        adoption = _adaptive_check(adoption, sub, predictors, validation, out, reference_name(current), components)
        if adoption.adopt:
            files |= {"prior": str(out / UNIT_PRIOR), "model_config": str(out / UNIT_CONFIG)}
    progress(("adopted: " if adoption.adopt else "not adopted: ") + adoption.reason)
    report = {"twin": machine.name, "recording": rec.source, "train_h": train_h, "validate_h": validate_h,
              "recording_h": float(rec.time_s[-1] - rec.time_s[0]) / 3600.0,
              "probes": {"train": fit.probes_train, "validation": adoption.probes,
                         "held_out": int((sub.time_s > train_until).sum()),
                         "noise": {c: sub.noise[c] for c in fit.components}, "notes": probes.notes},
              "adoption": adoption.as_dict(), "tested_against": tested_against,
              "parameters": moved_parameters(final_cal) if final_cal else [],
              "fixed": final_cal.fixed if final_cal else [],
              "structure": {"words": [t.as_dict() for t in st.words], "tried": [t.as_dict() for t in st.tried],
                            "first_calibration": moved_parameters(fit.calibration) if st.words else None,
                            "recalibration": st.recalibration,
                            "wall_s": round(st.wall_s, 1), "twin_runs": st.evals},
              "held_out_scores": score_table(sub, predictors, sub.time_s > train_until), "finder": finder,
              "files": files,
              "wall_s": {"calibration": round(t_fit, 1), "structure": round(t_struct, 1),
                         "priors_and_scores": round(time.perf_counter() - t1, 1)},
              "twin_simulated_h_per_s": round(fit.calibration.simulated_h / max(fit.calibration.wall_s, 1e-9), 1)}
    (out / "report.json").write_text(json.dumps(finite_figures(report), indent=1, allow_nan=False) + "\n")
    return report


def _adaptive_check(open_loop: Adoption, sub: ProbeSet, predictors: dict, validation, out: pathlib.Path,
                    reference: str, components: dict[str, list[str]]) -> Adoption:
    """An open-loop adoption stands only if the adaptive model from the unit's prior also beats
    the one from the ``reference`` prior (the type's or the one running now) on the validation
    probes (each predicted before it was seen) and has its components (else the running model
    could not be swapped for it); a prior that is not adopted is not left behind."""
    if not open_loop.adopt:
        return open_loop
    if components.get("unit prior") != components.get(reference):
        adaptive = Adoption(False, f"of other components ({components.get('unit prior')}) than the {reference} "
                                   f"({components.get(reference)})")
    else:
        adaptive = decide(sub.values, sub.noise, predictors[f"adaptive, {reference}"],
                          predictors["adaptive, unit prior"], validation, margin=ADAPTIVE_MARGIN)
    if adaptive.adopt:
        return Adoption(True, f"twin open loop {open_loop.reason}; adaptive model against the {reference} "
                              f"{adaptive.reason}", open_loop.rmse, open_loop.probes)
    for name in (UNIT_PRIOR, UNIT_CONFIG):
        (out / name).unlink(missing_ok=True)
    return Adoption(False, f"the twin is better open loop, but the adaptive model from its prior against the "
                           f"{reference} is {adaptive.reason}", open_loop.rmse, open_loop.probes)

