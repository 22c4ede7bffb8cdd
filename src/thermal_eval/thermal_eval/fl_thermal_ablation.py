"""Issue 19 item 6: conceal a mechanism of a twin calibrated on the real FL_THERMAL recording.

The twin (default the ``fl-thermal-rig`` preset, built for this rig; its sensor placement is
an assumption stated in the preset's header) is calibrated on the training rows of FL_THERMAL
(``thermal_twin.calibration.calibrate``, the preset's ranges and prior). That calibrated twin
is the reference. For each mechanism of :func:`mechanisms` the mechanism is removed from the
calibrated twin and the ablated twin is diagnosed against the real recording; a row says
whether the finder names the removed mechanism first (effect and target), how close its
fitted parameter comes to the calibrated value, and how much of the held-out fit the removal
lost it restores (``restored_pct``: 100 = back to the calibrated twin's held-out weighted
SSE), with the channels the removal changes most. The last row repeats the bearing case with
the speed column deleted: the speed is first estimated from the temperatures
(``input_estimation.fill_missing_inputs``) with the ablated twin.
``thermal-comp bench diagnose`` does not run this (minutes); the slow test and
docs/diagnose.md do.
"""
from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from thermal_twin.calibration import calibrate
from thermal_twin.column_mapping import parse_mapping, read_real_recording
from thermal_twin.input_estimation import fill_missing_inputs
from thermal_twin.machine_schema import load_machine
from thermal_twin.mismatch_diagnosis import diagnose, shared_channels
from thermal_twin.mismatch_fit import FitProblem
from thermal_comp_common.recording_csv import Recording
from thermal_eval.fl_thermal_data import default_csv_path


@dataclass(frozen=True)
class Mechanism:
    label: str
    expect: str                        # effect:target the finder should name first
    param: str                         # the fitted parameter compared with the calibrated value
    remove: Callable[[dict], float]    # removes the mechanism in place, returns its reference value


def _drop_override(spec: dict, name: str) -> None:
    """A removed parameter leaves the twin's calibration section too (else the ablated
    description names a parameter it no longer has and is invalid)."""
    (spec.get("calibration") or {}).get("parameters", {}).pop(name, None)


def _bearing(spec: dict, umax: float) -> float:
    _drop_override(spec, "sources.front_bearing_friction.coefficient")
    s = spec["sources"].pop("front_bearing_friction")
    return float(s["coefficient"]) * umax ** float(s.get("exponent", 1.0))


def _ambient_link(spec: dict, link: str) -> float:
    _drop_override(spec, f"links.{link}.conductance")
    return float(spec["links"].pop(link)["conductance"])


def _gain(spec: dict, channel: str, node: str) -> float:
    _drop_override(spec, f"errors.{channel}.terms.{node}")
    return float(spec["errors"][channel]["terms"].pop(node))


def _lag(spec: dict, sensor: str) -> float:
    lag = float(spec["sensors"][sensor].get("lag_s", 0.0))
    spec["sensors"][sensor]["lag_s"] = 0.0
    return lag


def mechanisms(umax: float, twin: str = "fl-thermal-rig") -> list[Mechanism]:
    """The removed mechanisms: the speed-driven bearing source, the structure's ambient
    link, one thermo-elastic term, one sensor's lag (for ``spindle-stand``: those of the
    first, negative table in docs/diagnose.md)."""
    link, sensor = ("column_ambient", "t7") if twin == "spindle-stand" else ("headstock_ambient", "t5")
    node = link.split("_")[0]
    return [
        Mechanism("front bearing heat (speed-driven source)", "heat_source:front_bearing", "P_max",
                  lambda s: _bearing(s, umax)),
        Mechanism(f"{node}-ambient link (structure)", f"ambient_coupling:{node}", "dG",
                  lambda s: _ambient_link(s, link)),
        Mechanism("thermo-elastic gain ch5/headstock", "elastic_gain:ch5_um/headstock", "d_gain",
                  lambda s: _gain(s, "ch5_um", "headstock")),
        Mechanism(f"lag of sensor {sensor}", f"time_lag:{sensor}", "tau", lambda s: _lag(s, sensor)),
    ]


def _holdout_sse(problem: FitProblem, spec: dict) -> float:
    return float(np.sum(_holdout_by_channel(problem, spec)))


def _holdout_by_channel(problem: FitProblem, spec: dict) -> np.ndarray:
    return np.sum(problem.weighted_residual(problem.outputs(spec), problem.n_train) ** 2, axis=1)


def most_changed(problem: FitProblem, spec_a: dict, spec_b: dict, k: int = 4) -> list[tuple[str, float]]:
    """The k channels whose held-out weighted SSE changes most (ratio b / a, furthest from 1)
    from ``spec_a`` to ``spec_b``: what the held-out score of a removal is made of."""
    a, b = _holdout_by_channel(problem, spec_a), _holdout_by_channel(problem, spec_b)
    ratio = [(c, float(b[i] / a[i])) for i, c in enumerate(problem.channels) if a[i] > 0]
    return sorted(ratio, key=lambda x: -abs(np.log(max(x[1], 1e-12))))[:k]


def _row(mech: Mechanism, ref: float, rep: dict, sse: dict, wall: float) -> dict:
    sel = [] if rep["selected"] == "none" else rep["selected"]
    first = f"{sel[0]['effect']}:{sel[0]['target']}" if sel else rep["answer"]
    value = None
    if sel and mech.param in sel[0]["params"]:
        value = float(sel[0]["params"][mech.param]["value"])
    lost = sse["ablated"] - sse["calibrated"]
    # where the removed mechanism ranks among the first round's fitted hypotheses
    r1 = [h for h in rep["hypotheses"] if h["round"] == 1]
    rank = next((i + 1 for i, h in enumerate(r1) if f"{h['effect']}:{h['target']}" == mech.expect), None)
    exp_h = r1[rank - 1] if rank else None
    exp_value = (float(exp_h["params"][mech.param]["value"])
                 if exp_h and mech.param in exp_h["params"] else None)
    return {"expected_rank_round1": rank, "expected_fitted": exp_value,
            "expected_holdout_improvement_pct": exp_h["holdout_improvement_pct"] if exp_h else None,
            "hypotheses_round1": len(r1),
            "mechanism": mech.label, "expected": mech.expect, "answer": rep["answer"], "first": first,
            "effect_ok": bool(sel) and sel[0]["effect"] == mech.expect.split(":")[0],
            "target_ok": first == mech.expect, "parameter": mech.param, "reference": ref, "fitted": value,
            "rel_error_pct": (None if value is None or ref == 0 else 100.0 * abs(value - ref) / abs(ref)),
            "holdout_sse_calibrated": sse["calibrated"], "holdout_sse_ablated": sse["ablated"],
            "holdout_sse_after": sse["after"],
            "restored_pct": (100.0 * (sse["ablated"] - sse["after"]) / lost if lost > 0 else None),
            "diagnosis_wall_s": wall}


def run(csv: str | None = None, progress: Callable[[str], None] | None = print,
        twin: str = "fl-thermal-rig") -> dict:
    """Calibrate ``twin``, then ablate and diagnose each mechanism; returns the table's rows
    and the calibration's figures."""
    rec = read_real_recording(str(csv or default_csv_path()), parse_mapping(None, []),
                              "temperatures", "errors/ground_truth")
    t0 = time.perf_counter()
    cal = calibrate(twin, rec)
    cal_fig = {"twin": twin, "wall_s": time.perf_counter() - t0, "evaluations": cal.n_evals,
               "free_parameters": len(cal.estimates), "status": cal.status,
               "at_bound": [e.param.name for e in cal.estimates if "at bound" in e.flags],
               "holdout_rmse": {c: (v["holdout_rmse_before"], v["holdout_rmse_after"])
                                for c, v in cal.channel_table().items()}}
    if progress:
        progress(f"calibrated {len(cal.estimates)} parameters in {cal_fig['wall_s']:.1f} s")
    spec_c = cal.spec
    machine = load_machine(spec_c)
    chans = shared_channels(machine, rec)
    n_train = int(round(len(rec) * (2.0 / 3.0)))
    res = {machine.sensors[s].column: machine.sensors[s].resolution for s in machine.sensors}
    problem = FitProblem(rec, chans, n_train, resolution=res)
    umax = float(np.nanmax(np.abs(rec.columns["spindle_rpm"])))
    rows = []
    sse_c = _holdout_sse(problem, spec_c)
    cases = [(m, rec) for m in mechanisms(umax, twin)]
    speedless = Recording(rec.time_s, {k: v for k, v in rec.columns.items() if k != "spindle_rpm"},
                          source=rec.source + " (spindle_rpm deleted)")
    cases.append((mechanisms(umax, twin)[0], speedless))
    for mech, r in cases:
        ablated = copy.deepcopy(spec_c)
        ref = mech.remove(ablated)
        note = ""
        if r is speedless:
            am = load_machine(ablated)
            r, _, found = fill_missing_inputs(am, r, shared_channels(am, r))
            note = "; ".join(found)
        t1 = time.perf_counter()
        d = diagnose(ablated, r)
        wall = time.perf_counter() - t1
        after = d.augmented_spec or ablated
        # scored on the recording the finder saw (with the estimated speed in the last row)
        prob = problem if r is rec else FitProblem(r, chans, n_train, resolution=res)
        sse = {"calibrated": sse_c if r is rec else _holdout_sse(prob, spec_c),
               "ablated": _holdout_sse(prob, ablated), "after": _holdout_sse(prob, after)}
        row = _row(mech, ref, d.report, sse, wall)
        row["recording"] = "speed deleted, estimated" if note else "FL_THERMAL"
        row["most_changed"] = most_changed(prob, spec_c, ablated)
        row["note"] = note
        rows.append(row)
        if progress:
            progress(f"{row['mechanism']} [{row['recording']}]: first {row['first']} (expected {row['expected']}), "
                     f"{row['parameter']} {row['fitted']} vs {row['reference']:.4g}, restored "
                     f"{row['restored_pct']} %, {wall:.0f} s")
    return {"calibration": cal_fig, "rows": rows}


def markdown(result: dict) -> str:
    """The docs table."""
    L = ["| removed mechanism | recording | held-out SSE ablated / calibrated | named first | effect | target "
         "| parameter: fitted / calibrated | held-out fit restored | removed mechanism's rank, its fit "
         "| channels the removal changes most (held-out SSE x) |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        par = (f"{r['parameter']}: {r['fitted']:.4g} / {r['reference']:.4g} ({r['rel_error_pct']:.0f} %)"
               if r["fitted"] is not None else f"{r['parameter']}: - / {r['reference']:.4g}")
        rest = f"{r['restored_pct']:.0f} %" if r["restored_pct"] is not None else "-"
        if r["expected_rank_round1"]:
            ev = "-" if r["expected_fitted"] is None else f"{r['expected_fitted']:.4g}"
            exp = (f"{r['expected_rank_round1']} of {r['hypotheses_round1']}: {r['parameter']} {ev}, "
                   f"held-out {r['expected_holdout_improvement_pct']:.0f} %")
        else:
            exp = f"not among the {r['hypotheses_round1']} fitted"
        ratio = r["holdout_sse_ablated"] / r["holdout_sse_calibrated"]
        L.append(f"| {r['mechanism']} | {r['recording']} | {ratio:.3f} | {r['first']} | {'yes' if r['effect_ok'] else 'no'} "
                 f"| {'yes' if r['target_ok'] else 'no'} | {par} | {rest} | {exp} "
                 f"| {', '.join(f'{c} {x:.2f}' for c, x in r.get('most_changed', []))} |")
    return "\n".join(L)


if __name__ == "__main__":
    import json
    import sys
    out = run(twin=sys.argv[1] if len(sys.argv) > 1 else "fl-thermal-rig")
    print(markdown(out))
    print(json.dumps(out, indent=1, default=str))
