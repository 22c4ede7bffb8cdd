"""``thermal-comp learn`` on several runs of one unit: the unit twin calibrated on the training
runs jointly (learn.runs.fit), adopted only if better on the validation probes (open loop, then
its prior's adaptive model against the prior it would replace: learn.adoption, as for one
recording), and scored on every run it was not fitted on, per run and pooled: the twins open
loop, the type's (or current) and the unit's prior replayed over each run from a fresh model
(the run's own start and probing clock), beside holding the run's last probe, the training
probes' mean and a static regression fitted on the training runs. No rclpy.

After the joint calibration, learn's words for what the calibration cannot say are searched on
the same runs (learn.runs.structure_runs), each judged on the validation probes.
"""
from __future__ import annotations

import json
import math
import pathlib
import time
from typing import Any, Callable, Sequence

import numpy as np
import yaml

from talc_model.prior.dispatch import model_from_prior
from thermal_comp_common.json_figures import finite_figures
from thermal_comp_common.run_splits import RunFold
from thermal_twin.machine.schema import Machine, load_machine

from thermal_eval.learn.adoption import Adoption, decide
from thermal_eval.learn.command import (UNIT_CONFIG, UNIT_PRIOR, UNIT_TWIN, _adaptive_check, _prior_models,
                                        moved_parameters, reference_name)
from thermal_eval.learn.current import CurrentPrior
from thermal_eval.learn.probe_score import hold_last, prequential_model, score_table
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.learn.runs.fit import RunsFit, fit_runs
from thermal_eval.learn.runs.sources import CellRun
from thermal_eval.learn.runs.structure_runs import runs_words
from thermal_eval.learn.structure import twin_outputs


def _sub(run: CellRun, components: list[str]) -> ProbeSet:
    p = run.probes
    return ProbeSet(p.time_s, {c: p.values[c] for c in components}, {c: p.noise[c] for c in components}, run.name)


def _at_probes(spec: dict, run: CellRun, components: list[str]) -> dict[str, np.ndarray]:
    """The description's open-loop errors (since the run's start) at the run's probe instants."""
    out = twin_outputs(spec, run.rec)
    idx = np.searchsorted(run.rec.time_s, run.probes.time_s)
    return {c: np.asarray(out[c], float)[idx] for c in components}


def _features(run: CellRun, sensors: list[str]) -> np.ndarray:
    """Temperatures at the run's probe instants, relative to the run's first row, and a 1."""
    idx = np.searchsorted(run.rec.time_s, run.probes.time_s)
    cols = [np.asarray(run.rec.columns[s], float) for s in sensors]
    return np.column_stack([c[idx] - c[0] for c in cols] + [np.ones(idx.size)])


def pooled_baselines(runs: Sequence[CellRun], fit: RunsFit) -> dict[int, dict[str, dict[str, np.ndarray]]]:
    """Per run: the training probes' mean and a least-squares regression of the training probes on
    the temperatures (each run relative to its own start), both fitted on the probes the twin was
    fitted on, and holding the run's own last probe (NaN before its first)."""
    sensors = [s for s in runs[0].rec.names("sensor")
               if all(np.isfinite(np.asarray(r.rec.columns[s], float)).all() for r in runs)]
    fitted = {i: runs[i].probes.time_s <= u for i, u in fit.fit_until.items()}
    out: dict[int, dict[str, dict[str, np.ndarray]]] = {i: {"hold last probe": hold_last(_sub(r, fit.components))}
                                                        for i, r in enumerate(runs)}
    X = {i: _features(r, sensors) for i, r in enumerate(runs)}
    for c in fit.components:
        y = np.concatenate([runs[i].probes.values[c][m] for i, m in fitted.items()])
        A = np.vstack([X[i][m] for i, m in fitted.items()])
        ok = np.isfinite(y)
        mean = float(np.mean(y[ok])) if ok.any() else math.nan
        beta = np.linalg.lstsq(A[ok], y[ok], rcond=None)[0] if ok.sum() >= A.shape[1] + 2 else None
        for i, r in enumerate(runs):
            n = r.probes.time_s.size
            out[i].setdefault("training mean", {})[c] = np.full(n, mean)
            out[i].setdefault("static regression", {})[c] = X[i] @ beta if beta is not None else np.full(n, math.nan)
    return out


def _pooled(runs: Sequence[CellRun], idx: Sequence[int], predictors: dict, masks: dict, components: list[str]):
    """(probes, predictors, mask) of the runs ``idx`` laid end to end (one probe clock)."""
    times, off = [], 0.0
    for i in idx:
        t = runs[i].probes.time_s
        times.append(t - (t[0] if t.size else 0.0) + off)
        off = (times[-1][-1] if t.size else off) + 1.0
    cat = lambda get: {c: np.concatenate([get(i, c) for i in idx]) for c in components}  # noqa: E731
    sub = ProbeSet(np.concatenate(times), cat(lambda i, c: runs[i].probes.values[c]),
                   {c: runs[idx[0]].probes.noise[c] for c in components}, "runs")
    names = [n for n in predictors[idx[0]] if all(n in predictors[i] for i in idx)]
    preds = {n: cat(lambda i, c, n=n: predictors[i][n][c]) for n in names}
    return sub, preds, np.concatenate([masks[i] for i in idx])


def _roles(fold: RunFold) -> dict[int, str]:
    return {i: "train" for i in fold.train} | {i: "validation" for i in fold.validation} | \
        {i: "test" for i in fold.test}


def write_runs_twin(fit: RunsFit, runs: Sequence[CellRun], out: pathlib.Path, spec: dict | None = None
                    ) -> pathlib.Path:
    """The calibrated twin (with its words when given ``spec``) as a machine YAML (validated on
    the way back in)."""
    spec = dict(fit.spec if spec is None else spec)
    names = ", ".join(runs[i].name for i in fit.fit_until)
    spec["description"] = f"{fit.machine.description} -- learned from runs {names}".strip()
    path = out / UNIT_TWIN
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    load_machine(str(path))
    return path


def learn_runs(twin, runs: Sequence[CellRun], fold: RunFold, out: pathlib.Path, validate_h: float | None = None,
               max_nfev: int = 20, progress: Callable[[str], None] = lambda m: None, build_priors: bool = True,
               current: CurrentPrior | None = None, words: bool = True) -> dict[str, Any]:
    """Learn the unit from ``fold``'s training runs (module docstring); write its files into
    ``out``; the report as a dict (also ``out/report.json``). ``words``: search them."""
    t0 = time.perf_counter()
    machine = twin if isinstance(twin, Machine) else load_machine(twin)
    fit = fit_runs(machine, runs, fold, validate_h, max_nfev, progress)
    comps = fit.components
    st, unit_spec = runs_words(fit, runs, progress) if words else (None, None)
    unit_spec = fit.spec if unit_spec is None else unit_spec
    out.mkdir(parents=True, exist_ok=True)
    unit_path = write_runs_twin(fit, runs, out, unit_spec)
    roles = _roles(fold)
    order = sorted(roles)
    scored = {i: (np.ones(runs[i].probes.time_s.size, bool) if roles[i] != "train" else
                  runs[i].probes.time_s > fit.fit_until[i]) for i in order}
    preds = pooled_baselines(runs, fit)
    type_spec = machine.to_dict()
    for i in order:
        preds[i]["twin (type), open loop"] = _at_probes(type_spec, runs[i], comps)
        preds[i]["twin (unit), open loop"] = _at_probes(unit_spec, runs[i], comps)
    val_idx = sorted(fit.validation)
    masks = {i: fit.validation.get(i, np.zeros(runs[i].probes.time_s.size, bool)) for i in order}
    vsub, vpred, vmask = _pooled(runs, val_idx, preds, masks, comps)
    adoption = decide(vsub.values, vsub.noise, vpred["twin (type), open loop"], vpred["twin (unit), open loop"], vmask)
    t1 = time.perf_counter()
    files, tested_against = {"unit_twin": str(unit_path)}, None
    if build_priors:
        current, priors = _prior_models(machine, unit_path, out, progress, adoption.adopt, current)
        tested_against, components = current.as_dict(), {}
        for name, (cfg, prior) in priors.items():
            for i in order:
                progress(f"replaying run {runs[i].name!r} with the {name} (a fresh model from its start)")
                model = model_from_prior(prior.get("model_kind", "talc"), cfg, prior)
                components[name] = list(model.component_names)
                preds[i][f"adaptive, {name}"] = prequential_model(model, runs[i].rec, _sub(runs[i], comps))
        vsub, vpred, vmask = _pooled(runs, val_idx, preds, masks, comps)
        adoption = _adaptive_check(adoption, vsub, vpred, vmask, out, reference_name(current), components)
        if adoption.adopt:
            files |= {"prior": str(out / UNIT_PRIOR), "model_config": str(out / UNIT_CONFIG)}
    progress(("adopted: " if adoption.adopt else "not adopted: ") + adoption.reason)
    report = _report(machine, runs, fold, fit, roles, scored, preds, adoption, tested_against, files)
    report["structure"] = None if st is None else {
        "words": [t.as_dict() for t in st.words], "tried": [t.as_dict() for t in st.tried],
        "wall_s": round(st.wall_s, 1), "twin_runs": st.evals,
        "note": "the words are kept with the joint calibration's parameters (no recalibration with them)"}
    report["wall_s"] = {"calibration": round(fit.wall_s, 1), "priors_and_scores": round(time.perf_counter() - t1, 1),
                        "total": round(time.perf_counter() - t0, 1)}
    (out / "report.json").write_text(json.dumps(finite_figures(report), indent=1, allow_nan=False) + "\n")
    return report


def _run_row(run: CellRun, role: str, fit: RunsFit, i: int, scored: np.ndarray) -> dict[str, Any]:
    e = run.entry
    until = fit.fit_until.get(i)
    return {"name": e.name, "path": e.path, "unit": e.unit, "programme": e.programme, "date": e.date,
            "hall_setpoint_c": e.hall_setpoint_c, "role": role, "hours": round(run.hours, 3),
            "probes": int(run.probes.time_s.size),
            "fitted_until_h": None if until is None else (round(run.hours, 3) if math.isinf(until) else
                                                          round((until - float(run.rec.time_s[0])) / 3600.0, 3)),
            "validation_probes": int(fit.validation[i].sum()) if i in fit.validation else 0,
            "scored_probes": int(scored.sum())}


def _report(machine, runs, fold, fit: RunsFit, roles, scored, preds, adoption: Adoption, tested_against,
            files) -> dict[str, Any]:
    comps = fit.components
    per_run = {runs[i].name: score_table(_sub(runs[i], comps), preds[i], scored[i]) for i in roles if scored[i].any()}
    pooled = {}
    for role in ("test", "validation", "train"):
        idx = [i for i in sorted(roles) if roles[i] == role and scored[i].any()]
        if idx:
            sub, p, mask = _pooled(runs, idx, preds, scored, comps)
            pooled[role] = score_table(sub, p, mask)
    cal = fit.calibration
    return {"twin": machine.name, "runs": [_run_row(runs[i], roles[i], fit, i, scored[i]) for i in sorted(roles)],
            "split": fold.name, "validation_rule": fit.rule,
            "probes": {"noise": {c: runs[0].probes.noise[c] for c in comps}, "notes": runs[0].probes.notes},
            "adoption": adoption.as_dict(), "tested_against": tested_against,
            "parameters": moved_parameters(cal), "fixed": cal.fixed,
            "scores": {"per_run": per_run, "pooled": pooled}, "files": files,
            "twin_simulated_h_per_s": round(cal.simulated_h / max(cal.wall_s, 1e-9), 1)}
