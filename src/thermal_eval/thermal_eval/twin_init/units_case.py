"""``bench twin-init``, part (a): nmv5000 units whose physics differs from the type's twin
(thermal_eval.learn.units), with NO preset given. The cell runs TALC without a prior (the
thesis's protocol, without the type's soft sensors: there is no twin) for the first day and
records its probes; ``twin init`` makes a twin from that day (temperatures, machine inputs, the
probes; no true hall, no ground truth) and the nmv5000 description a user can write
(descriptions/nmv5000.yaml); a TALC prior is built on that twin (its soft sensors are that
twin's nodes) on the type's load programmes, and a TALC from it takes over at 24 h (it first
runs over the recorded day with its probes). Figures over the rest of the run: P99_lin and its
ratio to probe-and-hold at the model's own Q_prod, beside the no-prior TALC running on and, as a
reference that needs the preset, the type's prior running on.
"""
from __future__ import annotations

import pathlib
import time

import numpy as np
import yaml

import talc_model
from talc_model.adaptive_model import make_model
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import load_prior
from thermal_comp.prior.build import build_prior, cached_prior, default_config, training_scenarios
from thermal_comp_common.recording_csv import Recording
from thermal_twin.identify import init_twin, load_description
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

from thermal_eval.learn.bench import cell_view, recorded_probes
from thermal_eval.learn.probe_score import prequential_model
from thermal_eval.learn.units import structural_unit
from thermal_eval.learn.unit_fit import probe_recording
from thermal_eval.replay.baseline_beside import beside_in_window
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM, probe_noise
from thermal_eval.replay.virtual_experiment import run_virtual_experiment

SCENARIO = "talc-178h-dry"
DESCRIPTION = pathlib.Path(__file__).with_name("descriptions") / "nmv5000.yaml"
SHIPPED_CONFIG = pathlib.Path(talc_model.__file__).with_name("config") / "talc_nmv5000.yaml"


def no_twin_config() -> dict:
    """TALC's shipped nmv5000 parameters without a type twin (what a user without a preset runs)."""
    cfg = yaml.safe_load(SHIPPED_CONFIG.read_text())
    cfg.pop("type_model", None)
    cfg.pop("type_input_names", None)
    return cfg


def init_twin_config(twin_path: pathlib.Path, soft_sensors: list[str]) -> dict:
    """The same parameters with the init twin as the soft-sensor twin (``twin:<node>`` names of the
    nodes its errors use). Its predicted errors ``twin:<error>`` as TALC's inputs were tried on the
    tuning unit: the prior found no stable ARX on them."""
    cfg = yaml.safe_load(SHIPPED_CONFIG.read_text())
    cfg["type_model"] = str(twin_path.resolve())
    cfg["type_input_names"] = list(soft_sensors)
    return cfg


def window_row(result, t_from: float, noise: dict, seed: int) -> dict:
    q = result.final_status["q_prod_pct"]
    row = beside_in_window(result, np.asarray(result.time_s) >= t_from, q, noise, PROBE_RESOLUTION_UM, seed=seed)
    row["q_prod_pct"] = q
    return row


def replay_from(rec: Recording, model, noise: dict, seed: int, start: int = 0):
    return run_virtual_experiment(rec, model, probe_noise_um=noise, probe_resolution_um=PROBE_RESOLUTION_UM,
                                  seed=seed, start=start, relative_errors=False, compute_metrics=False)


def unit_run(kind: str, seed: int, hours: float):
    """A structural unit's run with TALC from no prior probing on its own schedule, as a cell
    without a preset records it: (unit, recording, probe noise, that run, its recorded probes)."""
    unit = structural_unit(kind, seed)
    rec = simulate(unit.machine, make_timeline("nmv5000", SCENARIO, hours=hours, seed=seed), seed=seed).to_recording()
    cfg0 = no_twin_config()
    noise = probe_noise(list(cfg0["component_names"]))
    before = replay_from(rec, make_model("talc", cfg0), noise, seed)
    return unit, rec, noise, before, recorded_probes(before, rec, noise, seed)


def unit_case(kind: str, seed: int, hours: float, init_h: float, out: pathlib.Path, type_prior: bool = True,
              progress=lambda m: None,
              description: pathlib.Path = DESCRIPTION) -> dict:
    unit, rec, noise, before, probes = unit_run(kind, seed, hours)
    start = int(np.searchsorted(rec.time_s, rec.time_s[0] + init_h * 3600.0))
    day = probe_recording(cell_view(rec, unit.machine), probes, list(probes.values)).slice(0, start)
    day.source = f"nmv5000 unit #{seed} ({kind}), first {init_h:g} h"
    t0 = time.perf_counter()
    rep = init_twin(load_description(str(description)), day, out, progress=progress)
    t_init = time.perf_counter() - t0
    cfg = init_twin_config(pathlib.Path(rep["files"]["twin"]), rep["soft_sensors"])
    t0 = time.perf_counter()
    prior = build_prior(rep["files"]["twin"], cfg, training_scenarios("talc", "nmv5000"), kind="talc")
    t_prior = time.perf_counter() - t0
    model = model_from_prior("talc", cfg, prior)
    prequential_model(model, rec.slice(0, start), probes.window(t1=float(rec.time_s[start])))
    after = replay_from(rec, model, noise, seed, start=start)
    t_from = float(rec.time_s[start])
    rows = {"no prior running on": window_row(before, t_from, noise, seed),
            "init-twin prior from 24 h": window_row(after, t_from, noise, seed)}
    if type_prior:
        tcfg = default_config("nmv5000", "talc")
        path, _ = cached_prior("nmv5000", tcfg, training_scenarios("talc", "nmv5000"), kind="talc")
        rows["type prior running on (needs the preset)"] = window_row(
            replay_from(rec, model_from_prior("talc", tcfg, load_prior(path)), noise, seed), t_from, noise, seed)
    return {"unit": unit.name, "kind": kind, "seed": seed, "truth": unit.truth, "init_h": init_h,
            "hidden_bodies": rep["hidden_bodies"], "nodes": rep["nodes"],
            "init_held_out_rmse": rep["held_out_rmse"],
            "ratios": {k: v["p99_lin_ratio"] for k, v in rows.items()},
            "p99_lin_um": {k: v["model"]["p99_lin_um"] for k, v in rows.items()},
            "q_prod_pct": {k: v["q_prod_pct"] for k, v in rows.items()},
            "components_p99": {k: {c: d["p99"] for c, d in v["model"]["components"].items()} for k, v in rows.items()},
            "probes_first_day": int((probes.time_s < t_from).sum()),
            "wall_s": {"twin_init": round(t_init, 1), "prior": round(t_prior, 1)},
            "twin_simulated_h_per_s": rep["fit"]["simulated_h_per_s"]}
