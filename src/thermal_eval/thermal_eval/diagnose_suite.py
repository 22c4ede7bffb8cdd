"""The broadened concealed-effect suite of ``thermal-comp bench diagnose`` and its scores.

Cases on the ``mini_mill`` test twin (48 h, 300 s steps, seeded programmes): one hidden
vocabulary effect on many targets (regime-switched ones among them: coolant, door, a heat
source switched by the coolant), some with coloured AR(1) sensor noise and dropped rows,
recordings with nothing hidden, and out-of-vocabulary physics (sensor drift, quadratic
thermo-elastic term, speed x temperature product). Each is diagnosed against the
unmodified twin; :func:`score` turns the outcomes into the issue's figures.
"""
from __future__ import annotations

import pathlib
import time
from dataclasses import dataclass, field

from thermal_eval.mismatch_concealed import HiddenEffect as H, OutOfVocabulary as O, concealed_recording
from thermal_twin.machine_schema import load_machine
from thermal_twin.mismatch_diagnosis import diagnose

MINI_MILL = pathlib.Path(__file__).resolve().parents[2] / "thermal_twin" / "test" / "diagnose" / "mini_mill.yaml"
NOISY = {"ar1_sigma": 0.03, "drop_fraction": 0.02}


@dataclass
class Case:
    hidden: tuple = ()
    oov: tuple = ()
    seed: int = 1
    noise: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "unnamed" if self.oov else ("named" if self.hidden else "none")

    @property
    def label(self) -> str:
        keys = [h.key for h in self.hidden] + [o.key for o in self.oov]
        return ("+".join(keys) or "none") + f"-seed{self.seed}" + ("-ar1-drop" if self.noise else "")


SUITE = [
    Case((H("heat_source", "table", "spindle_rpm", (40.0, 1.0)),), seed=1),
    Case((H("heat_source", "head", "spindle_rpm", (25.0, 1.8)),), seed=2),
    Case((H("heat_source", "column", "coolant_on", (60.0,)),), seed=3),
    Case((H("ambient_coupling", "head", "ambient_degc", (4.0,)),), seed=1),
    Case((H("ambient_coupling", "table", "ambient_degc", (-3.0,)),), seed=2),
    Case((H("time_lag", "spindle", None, (1200.0,)),), seed=1),
    Case((H("time_lag", "E_Z0T", None, (2400.0,)),), seed=2),
    Case((H("speed_dependent_convection", "spindle", "spindle_rpm", (6.0,)),), seed=1),
    Case((H("coolant", "table", "coolant_on", (8.0, 16.0)),), seed=1),
    Case((H("door_event", "head", "door_open", (30.0,)),), seed=1),
    Case((H("door_event", "table", "door_open", (40.0,)),), seed=3),
    Case((H("sensor_bias", "column", None, (0.6,)),), seed=1),
    Case((H("elastic_gain", "E_Z0T/head", None, (1.0,)),), seed=1),
    Case((H("elastic_gain", "E_X0C/table", None, (-2.0,)),), seed=2),
    Case((H("periodic_load", "column", None, (30.0, 20.0)),), seed=1),
    Case((H("heat_source", "table", "spindle_rpm", (40.0, 1.0)),), seed=5, noise=NOISY),
    Case((H("door_event", "head", "door_open", (30.0,)),), seed=6, noise=NOISY),
    Case((H("ambient_coupling", "column", "ambient_degc", (5.0,)),), seed=7, noise=NOISY),
    Case(seed=1), Case(seed=2), Case(seed=3), Case(seed=4, noise=NOISY),
    Case(oov=(O("sensor_drift", "table", 0.01),), seed=1),
    Case(oov=(O("sensor_drift", "spindle", -0.008),), seed=2),
    Case(oov=(O("quadratic_elastic", "E_Z0T/spindle", 0.05),), seed=1),
    Case(oov=(O("product", "E_X0C/table", 1.0),), seed=1),
]


def run_case(spec: dict, case: Case, calibrate: bool = False) -> dict:
    rec, _ = concealed_recording(spec, case.hidden, hours=48.0, step_s=300.0, seed=case.seed,
                                 oov=case.oov, **case.noise)
    t0 = time.perf_counter()
    rep = diagnose(spec, rec, calibrate=calibrate).report
    wall = time.perf_counter() - t0
    sel = [] if rep["selected"] == "none" else rep["selected"]
    return {"case": case.label, "kind": case.kind, "answer": rep["answer"], "wall_s": wall,
            "true_key": (case.hidden[0].key if case.hidden else None),
            "selected": [f"{s['effect']}:{s['target']}:{s['driver'] or '-'}" for s in sel],
            "unnamed": rep["unnamed"],
            "calibration_wall_s": (rep["calibration"] or {}).get("wall_s")}


def score(outcomes: list[dict]) -> dict:
    """The issue's figures from the outcomes of :func:`run_case`."""
    named = [o for o in outcomes if o["kind"] == "named"]
    none = [o for o in outcomes if o["kind"] == "none"]
    oov = [o for o in outcomes if o["kind"] == "unnamed"]
    first = sum(o["answer"] == o["true_key"].split(":")[0] for o in named)
    exact = sum(bool(o["selected"]) and o["selected"][0] == o["true_key"] for o in named)
    extra = sum(max(0, len(o["selected"]) - 1) + (o["answer"] == "unnamed") for o in named)
    extra += sum(len(o["selected"]) + bool(o["unnamed"]) for o in none)
    extra += sum(len(o["selected"]) for o in oov)
    gains = [u["holdout_improvement_pct"] for o in oov if o["answer"] == "unnamed" for u in o["unnamed"]]
    walls = sorted(o["wall_s"] for o in outcomes)
    return {
        "cases": len(outcomes),
        "true_effect_first_pct": 100.0 * first / max(len(named), 1),
        "exact_target_pct": 100.0 * exact / max(len(named), 1),
        "extra_adopted_per_10_cases": 10.0 * extra / max(len(outcomes), 1),
        "none_answered": f"{sum(o['answer'] == 'none' for o in none)}/{len(none)}",
        "unnamed_answered": f"{sum(o['answer'] == 'unnamed' for o in oov)}/{len(oov)}",
        "unnamed_min_holdout_improvement_pct": min(gains) if gains else None,
        "diagnosis_wall_s_median": walls[len(walls) // 2] if walls else None,
        "diagnosis_wall_s_max": walls[-1] if walls else None,
    }


def mini_mill() -> dict:
    if not MINI_MILL.exists():
        raise FileNotFoundError(f"{MINI_MILL}: the suite needs the source tree's mini_mill test twin")
    return load_machine(MINI_MILL).to_dict()
