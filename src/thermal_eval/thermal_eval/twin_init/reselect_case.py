"""``bench twin-init`` part (a''): the product's loop re-choosing the init twin's structure at 48 h.
The cell runs as in part (a) (no prior on day 1, twin init from its first 24 h with the hidden
bodies chosen by the information criterion, that twin's prior from 24 h) and records the probes of
its own compensation over 24-48 h. At 48 h every candidate structure twin init fitted on day 1
(none saw day 2) is run open loop over the 48 h and scored on those probes
(thermal_twin.identify.rank_on_probes); the best-scoring one takes over only if it beats the
structure in use on them under ``learn``'s twin adoption rule (thermal_eval.learn.adoption.decide,
margin 1: no component worse beyond its probe uncertainty, smaller normalised SSE). Its prior first
runs over the 48 h with every recorded probe. Figures over 48-178 h beside the criterion's structure
running on, the no-prior TALC and the type prior. ``python -m thermal_eval.twin_init.reselect_case
KIND SEED OUT`` prints one unit's row as JSON.
"""
from __future__ import annotations

import json
import pathlib
import sys

import numpy as np
import yaml

from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import load_prior
from thermal_comp.prior.build import build_prior, cached_prior, default_config, training_scenarios
from thermal_twin.identify import init_twin, load_description, rank_on_probes
from thermal_twin.identify.command import soft_sensors
from thermal_twin.machine.schema import load_machine

from thermal_eval.learn.adoption import decide
from thermal_eval.learn.bench import cell_view, recorded_probes
from thermal_eval.learn.probe_score import prequential_model
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.learn.unit_fit import probe_recording
from thermal_eval.twin_init.units_case import DESCRIPTION, init_twin_config, replay_from, unit_run, window_row

CRITERION_ROW, ALWAYS_ROW, ADOPTED_ROW = ("criterion's structure from 24 h, running on",
                                          "best on day 2's probes from 48 h, always",
                                          "best on day 2's probes from 48 h if adopted")


def _prior_model(twin_path: str, soft_sensors: list[str], rec, probes: ProbeSet, stop: int):
    """A TALC from the prior built on ``twin_path``, run over the first ``stop`` rows with their probes."""
    cfg = init_twin_config(pathlib.Path(twin_path), soft_sensors)
    model = model_from_prior("talc", cfg, build_prior(twin_path, cfg, training_scenarios("talc", "nmv5000"),
                                                      kind="talc"))
    prequential_model(model, rec.slice(0, stop), probes.window(t1=float(rec.time_s[stop])))
    return model


def _joined(a: ProbeSet, b: ProbeSet) -> ProbeSet:
    return ProbeSet(np.concatenate([a.time_s, b.time_s]),
                    {c: np.concatenate([a.values[c], b.values[c]]) for c in a.values}, dict(a.noise), "cell")


def reselect_case(kind: str, seed: int, hours: float, out: pathlib.Path, init_h: float = 24.0,
                  decide_h: float = 48.0, type_prior: bool = True) -> dict:
    unit, rec, noise, before, probes = unit_run(kind, seed, hours)
    t0 = float(rec.time_s[0])
    s1, s2 = (int(np.searchsorted(rec.time_s, t0 + h * 3600.0)) for h in (init_h, decide_h))
    cell = cell_view(rec, unit.machine)
    day1 = probes.window(t1=float(rec.time_s[s1]))
    day = probe_recording(cell, probes, list(probes.values)).slice(0, s1)
    day.source = f"nmv5000 unit #{seed} ({kind}), first {init_h:g} h"
    rep = init_twin(load_description(str(DESCRIPTION)), day, out)
    in_use = rep["hidden_bodies"]
    model = _prior_model(rep["files"]["twin"], rep["soft_sensors"], rec, day1, s1)
    after = replay_from(rec, model, noise, seed, start=s1)
    day2 = recorded_probes(after, rec, noise, seed).window(float(rec.time_s[s1]), float(rec.time_s[s2]))
    specs = {int(h): yaml.safe_load(pathlib.Path(p).read_text()) for h, p in rep["files"]["candidates"].items()}
    rows = np.searchsorted(rec.time_s, day2.time_s)
    ranked = rank_on_probes(specs, cell.slice(0, s2), rows, day2.values, day2.noise)
    by_h = {r.hidden: r for r in ranked}
    best = ranked[0].hidden
    adoption = decide(day2.values, day2.noise, by_h[in_use].predicted, by_h[best].predicted,
                      np.ones(day2.time_s.size, bool), margin=1.0) if best != in_use else None
    t_from = float(rec.time_s[s2])
    table = {"no prior running on": window_row(before, t_from, noise, seed),
             CRITERION_ROW: window_row(after, t_from, noise, seed)}
    if best != in_use:
        path = rep["files"]["candidates"][str(best)]
        switched = replay_from(rec, _prior_model(path, soft_sensors(load_machine(path)), rec, _joined(day1, day2), s2),
                               noise, seed, start=s2)
        table[ALWAYS_ROW] = window_row(switched, t_from, noise, seed)
    else:
        table[ALWAYS_ROW] = table[CRITERION_ROW]
    table[ADOPTED_ROW] = table[ALWAYS_ROW] if adoption is not None and adoption.adopt else table[CRITERION_ROW]
    if type_prior:
        tcfg = default_config("nmv5000", "talc")
        path, _ = cached_prior("nmv5000", tcfg, training_scenarios("talc", "nmv5000"), kind="talc")
        table["type prior running on (needs the preset)"] = window_row(
            replay_from(rec, model_from_prior("talc", tcfg, load_prior(path)), noise, seed), t_from, noise, seed)
    return {"unit": unit.name, "kind": kind, "seed": seed, "truth": unit.truth, "in_use": in_use, "best": best,
            "day2_cost": {str(r.hidden): round(r.cost, 2) for r in ranked}, "day2_probes": int(day2.time_s.size),
            "adopted": bool(adoption is not None and adoption.adopt),
            "reason": adoption.reason if adoption is not None else "the structure in use scored best on day 2",
            "criterion_ratio_from_24h": window_row(after, float(rec.time_s[s1]), noise, seed)["p99_lin_ratio"],
            "ratios": {k: v["p99_lin_ratio"] for k, v in table.items()},
            "components_p99": {k: {c: d["p99"] for c, d in v["model"]["components"].items()} for k, v in table.items()}}


if __name__ == "__main__":
    print(json.dumps(reselect_case(sys.argv[1], int(sys.argv[2]), 178.0, pathlib.Path(sys.argv[3])), default=str))
