"""``bench twin-init`` part (a) with an adoption test: the cell keeps its no-prior TALC after the
twin init at 24 h and runs the init-twin prior's TALC beside it (fed the same recorded probes,
each predicted before it is seen); at 48 h it switches to the init-twin prior only if that model
predicted the probes of 24-48 h better (``learn``'s rule, thermal_eval.learn.adoption.decide with
its adaptive margin: no component worse beyond its probe uncertainty, normalised SSE below the
margin). Figures over 48-178 h. ``python -m thermal_eval.twin_init.adoption_case KIND SEED OUT``
prints one unit's row as JSON.
"""
from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from talc_model.adaptive_model import make_model
from talc_model.prior.dispatch import model_from_prior
from thermal_comp.prior.build import build_prior, training_scenarios
from thermal_twin.identify import init_twin, load_description

from thermal_eval.learn.adoption import ADAPTIVE_MARGIN, decide
from thermal_eval.learn.bench import cell_view
from thermal_eval.learn.probe_score import prequential_model
from thermal_eval.learn.unit_fit import probe_recording
from thermal_eval.twin_init.units_case import (DESCRIPTION, init_twin_config, no_twin_config, replay_from, unit_run,
                                               window_row)


def adopted_case(kind: str, seed: int, hours: float, out: pathlib.Path, init_h: float = 24.0,
                 decide_h: float = 48.0) -> dict:
    unit, rec, noise, before, probes = unit_run(kind, seed, hours)
    t0 = float(rec.time_s[0])
    s1 = int(np.searchsorted(rec.time_s, t0 + init_h * 3600.0))
    s2 = int(np.searchsorted(rec.time_s, t0 + decide_h * 3600.0))
    day = probe_recording(cell_view(rec, unit.machine), probes, list(probes.values)).slice(0, s1)
    day.source = f"nmv5000 unit #{seed} ({kind}), first {init_h:g} h"
    rep = init_twin(load_description(str(DESCRIPTION)), day, out)
    cfg = init_twin_config(pathlib.Path(rep["files"]["twin"]), rep["soft_sensors"])
    prior = build_prior(rep["files"]["twin"], cfg, training_scenarios("talc", "nmv5000"), kind="talc")
    seen = probes.window(t1=float(rec.time_s[s2]))
    shadow = model_from_prior("talc", cfg, prior)
    pred_init = prequential_model(shadow, rec.slice(0, s2), seen)
    pred_none = prequential_model(make_model("talc", no_twin_config()), rec.slice(0, s2), seen)
    mask = seen.time_s >= float(rec.time_s[s1])
    adoption = decide(seen.values, seen.noise, pred_none, pred_init, mask, margin=ADAPTIVE_MARGIN)
    t_from = float(rec.time_s[s2])
    rows = {"no prior running on": window_row(before, t_from, noise, seed)}
    switched = window_row(replay_from(rec, shadow, noise, seed, start=s2), t_from, noise, seed)
    rows["init-twin prior from 48 h, always"] = switched
    rows["init-twin prior from 48 h if adopted"] = switched if adoption.adopt else rows["no prior running on"]
    return {"unit": unit.name, "kind": kind, "seed": seed, "truth": unit.truth, "hidden_bodies": rep["hidden_bodies"],
            "adopted": adoption.adopt, "reason": adoption.reason, "validation_probes": adoption.probes,
            "ratios": {k: v["p99_lin_ratio"] for k, v in rows.items()}}


if __name__ == "__main__":
    print(json.dumps(adopted_case(sys.argv[1], int(sys.argv[2]), 178.0, pathlib.Path(sys.argv[3]))))
