"""Issue 19 item 6, the speedless bearing row with the estimated speed's scale anchored physically.

The row of :mod:`thermal_eval.fl_thermal_ablation` (the front-bearing source removed from the
twin calibrated on FL_THERMAL, the speed column deleted) with
:func:`thermal_twin.input_scale_anchor.alternate_anchored` in place of ``alternate``: the
coolant balance (W = m_dot c_p of the jacket, t4 = the return) is fitted on the training rows
of the recording *with* the speed, like every other calibrated parameter, and then anchors the
scale of the speed estimated from the recording without it. Prints the figures the brief asks
for (estimated speed against the deleted one, the motor's heat, the finder's answer, P_max,
restored %) and writes them as JSON. Minutes of wall time: not part of ``bench diagnose``.
"""
from __future__ import annotations

import copy
import json
import sys
import time

import numpy as np

from thermal_twin.column_mapping import parse_mapping, read_real_recording
from thermal_twin.input_estimation import source_power
from thermal_twin.input_scale_anchor import alternate_anchored, coolant_balance
from thermal_twin.machine_schema import load_machine
from thermal_twin.mismatch_diagnosis import shared_channels
from thermal_twin.mismatch_fit import FitProblem
from thermal_comp_common.recording_csv import Recording
from thermal_eval.fl_thermal_ablation import (ALTERNATION_ROUNDS, RESPONSES, _against_true_heat, _calibrated,
                                              _holdout_sse, _row, _source_heat)
from thermal_eval.fl_thermal_data import default_csv_path
from thermal_eval.fl_thermal_mechanisms import all_mechanisms

TWIN = "fl-thermal-rig"


def _speed_figures(est, ablated: dict, speed: np.ndarray, t: np.ndarray) -> dict:
    """The anchored speed and the motor's heat at it against the deleted speed's."""
    u = est.input_series(t)
    m = load_machine(ablated)
    return {"speed_mean": float(np.mean(u)), "speed_max": float(np.max(u)),
            "true_speed_mean": float(np.mean(speed)), "true_speed_max": float(np.max(speed)),
            "motor_heat_mean_w": float(np.mean(source_power(m, est.input, u))),
            "motor_heat_true_mean_w": float(np.mean(source_power(m, est.input, speed)))}


def run(csv: str | None = None, rated_max: float | None = None, progress=print) -> dict:
    rec = read_real_recording(str(csv or default_csv_path()), parse_mapping(None, []),
                              "temperatures", "errors/ground_truth")
    spec_c, _ = _calibrated(TWIN, rec, progress)
    machine = load_machine(spec_c)
    chans = shared_channels(machine, rec)
    n_train = int(round(len(rec) * (2.0 / 3.0)))
    res = {machine.sensors[s].column: machine.sensors[s].resolution for s in machine.sensors}
    problem = FitProblem(rec, chans, n_train, resolution=res)
    speed = np.asarray(rec.columns["spindle_rpm"], dtype=float)
    balance = coolant_balance(machine, rec, "spindle_rpm", "coolant_degc", n_train)
    if progress:
        progress(f"coolant balance: W = {balance.heat_per_kelvin:.2f} W/K above {balance.level:.2f} degC, "
                 f"training-block corr {balance.fit_corr:.3f}")
    mech = next(m for m in all_mechanisms(spec_c, float(np.max(speed))) if m.expect == "heat_source:front_bearing")
    ablated = copy.deepcopy(spec_c)
    ref = mech.remove(ablated)
    speedless = Recording(rec.time_s, {k: v for k, v in rec.columns.items() if k != "spindle_rpm"},
                          source=rec.source + " (spindle_rpm deleted)")
    t0 = time.perf_counter()
    alt = alternate_anchored(ablated, speedless, balance, responses=RESPONSES[TWIN], rounds=ALTERNATION_ROUNDS,
                             rated_max=rated_max, progress=progress)
    wall = time.perf_counter() - t0
    r, d = alt.last.recording, alt.last.diagnosis
    prob = FitProblem(r, chans, n_train, resolution=res)
    sse = {"calibrated": _holdout_sse(problem, spec_c), "ablated": _holdout_sse(prob, ablated),
           "after": _holdout_sse(prob, d.augmented_spec or ablated)}
    row = _row(mech, ref, d.report, sse, wall)
    row["balance"] = {"heat_per_kelvin": balance.heat_per_kelvin, "level": balance.level,
                      "fit_corr": balance.fit_corr, "sources": list(balance.sources)}
    row["rounds"] = [{"first": a.first, "note": a.notes[0], **_against_true_heat(a.estimate, spec_c, rec),
                      **_speed_figures(a.estimate, ablated, speed, rec.time_s)} for a in alt.rounds]
    row["converged"] = alt.converged
    row["heat_w"] = _source_heat(d.report, mech.expect, r, spec_c, rec)
    row["first_selected"] = (None if d.report["selected"] == "none" else
                             {k: d.report["selected"][0].get(k) for k in ("effect", "target", "holdout_improvement_pct")})
    row["rated_max"] = rated_max
    row["top_round1"] = [{"hypothesis": f"{h['effect']}:{h['target']}", "holdout_pct": h["holdout_improvement_pct"]}
                         for h in d.report["hypotheses"] if h["round"] == 1][:3]
    row["calibrated_p_at_estimated_max_w"] = float(source_power(
        load_machine({**spec_c, "sources": {k: v for k, v in spec_c["sources"].items() if k == "front_bearing_friction"}}),
        "spindle_rpm", [max(a["speed_max"] for a in row["rounds"][-1:])])[0])
    return row


if __name__ == "__main__":
    out = run(rated_max=float(sys.argv[1]) if len(sys.argv) > 1 else None)
    print(json.dumps(out, indent=1, default=str))
