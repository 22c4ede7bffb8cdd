"""Conceal a mechanism of a twin calibrated on the real FL_THERMAL recording; the finder names it back?

The twin (default the ``fl-thermal-rig`` preset, built for this rig; its sensor placement is
an assumption stated in the preset's header) is calibrated on the training rows of FL_THERMAL
(``thermal_twin.calibrate.fit.calibrate``, the preset's ranges and prior). That calibrated twin
is the reference. Every mechanism of it is screened (:mod:`thermal_eval.fl_thermal.mechanisms`:
held-out SSE without it, calibrated twin only) and the selection rule picks those the recording
supports; each is removed from the calibrated twin and the ablated twin is diagnosed against
the real recording. A row says whether the finder names the removed mechanism first (effect
and target), how close its fitted parameter comes to the calibrated value, how much of the
lost held-out fit it restores (``restored_pct``: 100 = back to the calibrated twin's held-out
weighted SSE), what the finder marks indistinguishable from its answer, and the channels the
removal changes most. Then chosen mechanisms are ablated again with the speed column deleted
(``run(speedless=...)``: the bearing source, the rule's pick of docs/diagnose.md, or all): the
speed is estimated from the temperatures with the ablated twin, the coolant return t4 treated
as a response of the jacket's heat, not a driver (``RESPONSES``), then again with the finder's
augmented twin until its first answer repeats (``input_alternation.alternate``); each round's
estimated heat is compared with the deleted speed's heat (correlation, mean), and the named
source's mean heat with the removed one's (its P_max is at the estimated speed's maximum).
Each screened mechanism also gets its identifiability (:mod:`thermal_eval.fl_thermal.identifiability`). ``thermal-comp bench diagnose`` does not run this (minutes); the slow test
and docs/diagnose.md do.
"""
from __future__ import annotations

import copy
import functools
import time
from typing import Callable

import numpy as np

from thermal_twin.calibrate.fit import calibrate
from thermal_twin.calibrate.column_mapping import parse_mapping, read_real_recording
from thermal_twin.calibrate.input_alternation import alternate
from thermal_twin.calibrate.input_estimation import fill_missing_inputs, source_power
from thermal_twin.calibrate.input_scale_anchor import anchored_fill, coolant_balance
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.diagnosis import diagnose, shared_channels
from thermal_twin.diagnose.fit import FitProblem
from thermal_comp_common.recording_csv import Recording
from thermal_eval.fl_thermal.data import default_csv_path
from thermal_eval.fl_thermal.identifiability import identifiability
from thermal_eval.fl_thermal.mechanisms import (Mechanism, all_mechanisms, holdout_by_channel, ratios_by_channel,
                                                screen, screen_markdown, select)


def mechanisms(umax: float, twin: str = "fl-thermal-rig") -> list[Mechanism]:
    """For ``spindle-stand``: the removed mechanisms of the first, negative table in
    docs/diagnose.md (the bearing source, the column's ambient link, ch5/headstock, t7's lag).
    Other twins choose theirs by :func:`thermal_eval.fl_thermal.mechanisms.select`."""
    spec = load_machine(twin).to_dict()
    by = {m.label: m for m in all_mechanisms(spec, umax)}
    return [by["source front_bearing_friction (spindle_rpm-driven)"], by["link column_ambient (column-ambient)"],
            by["thermo-elastic term ch5_um/headstock"], by["lag of sensor t7"]]


def _holdout_sse(problem: FitProblem, spec: dict) -> float:
    return float(np.sum(holdout_by_channel(problem, spec)))


def most_changed(problem: FitProblem, spec_a: dict, spec_b: dict, k: int = 4) -> list[tuple[str, float]]:
    """The k channels whose held-out weighted SSE changes most from ``spec_a`` to ``spec_b``."""
    return ratios_by_channel(problem, holdout_by_channel(problem, spec_a), holdout_by_channel(problem, spec_b), k)


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
    # the same hypotheses ranked by their screening share: which step prefers a neighbour
    by_screen = sorted(r1, key=lambda h: -h["screening_err"])
    s_rank = next((i + 1 for i, h in enumerate(by_screen) if f"{h['effect']}:{h['target']}" == mech.expect), None)
    exp_value = (float(exp_h["params"][mech.param]["value"])
                 if exp_h and mech.param in exp_h["params"] else None)
    return {"expected_rank_round1": rank, "expected_screen_rank_round1": s_rank, "expected_fitted": exp_value,
            "expected_screening_err": exp_h["screening_err"] if exp_h else None,
            "first_screening_err": r1[0]["screening_err"] if r1 else None,
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


def _calibrated(twin: str, rec: Recording, progress) -> tuple[dict, dict]:
    """The calibrated twin's description and the calibration's figures."""
    t0 = time.perf_counter()
    cal = calibrate(twin, rec)
    fig = {"twin": twin, "wall_s": time.perf_counter() - t0, "evaluations": cal.n_evals,
           "free_parameters": len(cal.estimates), "status": cal.status,
           "at_bound": [e.param.name for e in cal.estimates if "at bound" in e.flags],
           "holdout_rmse": {c: (v["holdout_rmse_before"], v["holdout_rmse_after"])
                            for c, v in cal.channel_table().items()}}
    if progress:
        progress(f"calibrated {len(cal.estimates)} parameters in {fig['wall_s']:.1f} s")
    return cal.spec, fig


#: boundary inputs the missing speed's heat warms (the preset's header: t4 is the jacket's coolant
#: *return*), treated as responses when the speed is estimated (input_estimation.as_responses)
RESPONSES = {"fl-thermal-rig": ["coolant_degc"]}
#: rounds of the speedless row's joint re-estimation (speed estimate <-> finder's answer)
ALTERNATION_ROUNDS = 3
#: the speed's scale anchor of the speedless rows (input_scale_anchor: the coolant balance W of
#: the jacket, fitted on the training rows with the speed like every calibrated parameter):
#: (estimated input, the boundary input whose column is the coolant return)
ANCHORS = {"fl-thermal-rig": ("spindle_rpm", "coolant_degc")}


def _chosen(problem: FitProblem, spec_c: dict, umax: float, twin: str, at_bound: list[str]) -> tuple[list, list]:
    """(the screening rows of every mechanism with its identifiability, the mechanisms to
    diagnose). For ``spindle-stand`` the first table's four; otherwise every mechanism the
    support rule picks (identifiable or not: each one's outcome is reported), then the
    ch5/headstock term if the rule left it out (it is the term the brief asks about)."""
    every = all_mechanisms(spec_c, umax)
    rows = screen(problem, spec_c, every, set(at_bound))
    for r, i in zip(rows, identifiability(problem, spec_c, every)):
        r.update(identifiable=i["identifiable"], competitor=i["competitor"], distinct=i["distinct"])
    if twin == "spindle-stand":
        return rows, mechanisms(umax, twin)
    chosen = select(every, rows)
    extra = [m for m in every if m.label == "thermo-elastic term ch5_um/headstock" and m not in chosen]
    return rows, chosen + extra


#: which mechanisms are also ablated on the speedless recording (``run(speedless=...)``)
SPEEDLESS = ("bearing", "rule", "all")


def _keeps_speed_sources(mech: Mechanism, spec_c: dict) -> bool:
    """Whether the twin without ``mech`` keeps every speed-driven source of ``spec_c`` (the
    sources whose heat anchors the scale of a speed estimated from the temperatures)."""
    ablated = copy.deepcopy(spec_c)
    mech.remove(ablated)
    n = sum(1 for s in (spec_c.get("sources") or {}).values() if s.get("input"))
    return n == sum(1 for s in (ablated.get("sources") or {}).values() if s.get("input"))


def speedless_mechanisms(chosen: list[Mechanism], spec_c: dict, which: str = "bearing") -> list[Mechanism]:
    """The mechanisms ablated with the speed column deleted, in case order: the bearing source,
    then (``rule``) the support rule's top pick among those whose removal keeps every
    speed-driven source (the rule of docs/diagnose.md, item 6, stated before the run), then
    (``all``) the other chosen ones in the support rule's order."""
    if which not in SPEEDLESS:
        raise ValueError(f"speedless={which!r}: expected one of {', '.join(SPEEDLESS)}")
    bearing = next(m for m in chosen if m.expect == "heat_source:front_bearing")
    anchored = [m for m in chosen if m is not bearing and _keeps_speed_sources(m, spec_c)]
    order = [bearing] + anchored[:1] + [m for m in chosen if m is not bearing and m not in anchored[:1]]
    return order[:{"bearing": 1, "rule": 2, "all": len(order)}[which]]


def run(csv: str | None = None, progress: Callable[[str], None] | None = print,
        twin: str = "fl-thermal-rig", only: list[int] | None = None, speedless: str = "bearing",
        anchor: bool = True) -> dict:
    """Calibrate ``twin``, screen every mechanism, then ablate and diagnose the chosen ones on
    FL_THERMAL (case indices 0 .. n-1) and ``speedless_mechanisms(.., speedless)`` on the
    recording with the speed column deleted (indices n, n+1, ...; ``only``: those case indices),
    the estimated speed's scale anchored by the coolant balance where ``ANCHORS`` has one for
    ``twin`` (``anchor=False``: the unanchored estimate); returns the table's rows, the
    screening rows and the calibration's figures."""
    rec = read_real_recording(str(csv or default_csv_path()), parse_mapping(None, []),
                              "temperatures", "errors/ground_truth")
    spec_c, cal_fig = _calibrated(twin, rec, progress)
    machine = load_machine(spec_c)
    chans = shared_channels(machine, rec)
    n_train = int(round(len(rec) * (2.0 / 3.0)))
    res = {machine.sensors[s].column: machine.sensors[s].resolution for s in machine.sensors}
    problem = FitProblem(rec, chans, n_train, resolution=res)
    umax = float(np.nanmax(np.abs(rec.columns["spindle_rpm"])))
    screened, chosen = _chosen(problem, spec_c, umax, twin, cal_fig["at_bound"])
    no_speed = Recording(rec.time_s, {k: v for k, v in rec.columns.items() if k != "spindle_rpm"},
                         source=rec.source + " (spindle_rpm deleted)")
    rule = {m.label for m in select(all_mechanisms(spec_c, umax), screened)}
    ident = {r["mechanism"]: r["identifiable"] for r in screened}
    cases = [(m, rec) for m in chosen] + [(m, no_speed) for m in speedless_mechanisms(chosen, spec_c, speedless)]
    fill = fill_missing_inputs
    if anchor and twin in ANCHORS:
        balance = coolant_balance(machine, rec, *ANCHORS[twin], n_train)
        cal_fig["coolant_balance"] = {"heat_per_kelvin_w_k": balance.heat_per_kelvin, "level_degc": balance.level,
                                      "fit_corr": balance.fit_corr, "column": balance.column}
        fill = functools.partial(anchored_fill, balance=balance)
    rows = []
    for i, (mech, r) in enumerate(cases):
        if only is not None and i not in only:
            continue
        row = _case(mech, r, r is no_speed, spec_c, problem, (chans, n_train, res, RESPONSES.get(twin, []), fill))
        row["selected_by_rule"] = mech.label in rule
        row["identifiable"] = ident[mech.label]
        row["case"] = i
        rows.append(row)
        if progress:
            progress(_progress_line(row))
    return {"calibration": cal_fig, "screen": screened, "rows": rows}


def _progress_line(row: dict) -> str:
    """One case's figures as the run prints them."""
    line = (f"[{row['case']}] {row['mechanism']} [{row['recording']}]: first {row['first']} (expected "
            f"{row['expected']}; effect {row['effect_ok']}, target {row['target_ok']}), {row['parameter']} "
            f"{row['fitted']} vs {row['reference']:.4g} ({row['rel_error_pct']} %), restored "
            f"{row['restored_pct']} %, {row['diagnosis_wall_s']:.0f} s")
    e = row.get("estimate") or {}
    if e:
        line += (f"; estimated heat r = {e['corr_with_true_heat']:.2f}, {e['mean_power_w']:.0f} W mean vs "
                 f"{e['true_mean_power_w']:.0f} W, rounds {[a['first'] for a in row['alternation']]}")
    if row.get("heat_w"):
        line += f"; named source's mean heat {row['heat_w']['fitted_mean_w']} vs {row['heat_w']['calibrated_mean_w']:.1f} W"
    return line


def _case(mech: Mechanism, r: Recording, estimate: bool, spec_c: dict, problem: FitProblem, setup) -> dict:
    """Ablate ``mech`` from ``spec_c``, (estimate the missing speed,) diagnose, score."""
    chans, n_train, res, responses, fill = setup
    ablated = copy.deepcopy(spec_c)
    ref = mech.remove(ablated)
    note, est, rounds = "", {}, []
    t1 = time.perf_counter()
    if estimate:
        # the speed estimated with the ablated twin, the finder's answer, the speed estimated
        # again with the finder's augmented twin ... (input_alternation: until the answer repeats)
        alt = alternate(ablated, r, responses=responses, rounds=ALTERNATION_ROUNDS, fill=fill)
        r, d = alt.last.recording, alt.last.diagnosis
        note = "; ".join(alt.last.notes)
        est = _against_true_heat(alt.last.estimate, spec_c, problem.recording)
        rounds = [{"first": a.first, **_against_true_heat(a.estimate, spec_c, problem.recording)}
                  for a in alt.rounds]
        est["converged"] = alt.converged
        est["anchored"] = fill is not fill_missing_inputs
        est["speed"] = _speed_figures(alt.rounds[0].estimate, problem.recording)
    else:
        d = diagnose(ablated, r)
    wall = time.perf_counter() - t1
    after = d.augmented_spec or ablated
    # the ablated and augmented twins are scored on the recording the finder saw (with the
    # estimated speed in the last row), the reference always on the real recording: the
    # calibrated twin driven by the estimated speed is no reference (its own sources would
    # turn the estimated heat into more heat again)
    prob = problem if not estimate else FitProblem(r, chans, n_train, resolution=res)
    sse = {"calibrated": _holdout_sse(problem, spec_c), "ablated": _holdout_sse(prob, ablated),
           "after": _holdout_sse(prob, after)}
    row = _row(mech, ref, d.report, sse, wall)
    row["recording"] = "speed deleted, estimated" if estimate else "FL_THERMAL"
    row["most_changed"] = most_changed(prob, spec_c, ablated)
    row["note"] = note
    row["indistinguishable"] = _indistinguishable(d.report)
    row["estimate"] = est
    row["alternation"] = rounds
    if estimate and mech.kind == "source":
        row["heat_w"] = _source_heat(d.report, mech.expect, r, spec_c, problem.recording)
    return row


def _speed_figures(est, rec: Recording) -> dict:
    """Round 1's estimated speed against the deleted one (mean, max)."""
    u, speed = est.input_series(rec.time_s), np.asarray(rec.columns[est.input], dtype=float)
    return {"mean": float(np.mean(u)), "max": float(np.max(u)),
            "true_mean": float(np.mean(speed)), "true_max": float(np.max(speed))}


def _source_heat(report: dict, expect: str, r: Recording, spec_c: dict, rec: Recording) -> dict:
    """The speedless row's scale-free figure: the mean heat of the first hypothesis named
    ``expect`` (round 1) at the estimated speed against the removed source's mean heat at the
    recorded speed in the calibrated twin. P_max is the heat at the *estimated* speed's maximum,
    whose scale the temperatures fix only through the twin's remaining sources."""
    node = expect.split(":")[1]
    h = next((h for h in report["hypotheses"] if h["round"] == 1 and f"{h['effect']}:{h['target']}" == expect), None)
    true = sum(s.coefficient * np.abs(np.asarray(rec.columns[s.input], dtype=float)) ** s.exponent
               for s in load_machine(spec_c).sources.values() if s.input and s.node == node)
    out = {"calibrated_mean_w": float(np.mean(true)), "fitted_mean_w": None}
    if h is not None:
        u = np.abs(np.asarray(r.columns[h["driver"]], dtype=float)) if h.get("driver") in r.columns else None
        if u is not None and np.max(u) > 0:
            n = float(h["params"].get("exponent", {"value": 1.0})["value"])
            out["fitted_mean_w"] = float(h["params"]["P_max"]["value"] * np.mean((u / np.max(u)) ** n))
    return out


def _against_true_heat(e, spec_c: dict, rec: Recording) -> dict:
    """The estimated heat per block against the deleted speed's heat in the calibrated twin
    (its speed-driven sources at the recorded speed, block means): correlation and means."""
    true_p = source_power(load_machine(spec_c), e.input, rec.columns[e.input])
    k = np.clip(np.searchsorted(e.block_edges_s, rec.time_s, side="right") - 1, 0, len(e.power_w) - 1)
    tb = np.array([np.mean(true_p[k == b]) if np.any(k == b) else np.nan for b in range(len(e.power_w))])
    ok = np.isfinite(tb)
    return {"corr_with_true_heat": float(np.corrcoef(e.power_w[ok], tb[ok])[0, 1]),
            "mean_power_w": float(np.mean(e.power_w[ok])), "true_mean_power_w": float(np.mean(tb[ok])),
            "located": e.located}


def _indistinguishable(report: dict) -> list[str]:
    """What the finder's report marks as indistinguishable from its first answer."""
    sel = [] if report["selected"] == "none" else report["selected"]
    return list(sel[0].get("indistinguishable_from", [])) if sel else []


def markdown(result: dict) -> str:
    """The docs table."""
    L = ["| removed mechanism | recording | held-out SSE ablated / calibrated | named first | effect | target "
         "| parameter: fitted / calibrated | held-out fit restored | removed mechanism's rank, its fit "
         "| marked indistinguishable from the first | channels the removal changes most (held-out SSE x) |",
         "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        par = (f"{r['parameter']}: {r['fitted']:.4g} / {r['reference']:.4g} ({r['rel_error_pct']:.0f} %)"
               if r["fitted"] is not None else f"{r['parameter']}: - / {r['reference']:.4g}")
        rest = f"{r['restored_pct']:.0f} %" if r["restored_pct"] is not None else "-"
        if r["expected_rank_round1"]:
            ev = "-" if r["expected_fitted"] is None else f"{r['expected_fitted']:.4g}"
            exp = (f"{r['expected_rank_round1']} of {r['hypotheses_round1']} (screening rank "
                   f"{r['expected_screen_rank_round1']}): {r['parameter']} {ev}, "
                   f"held-out {r['expected_holdout_improvement_pct']:.0f} %")
        else:
            exp = f"not among the {r['hypotheses_round1']} fitted"
        ratio = r["holdout_sse_ablated"] / r["holdout_sse_calibrated"]
        if r.get("estimate"):
            e = r["estimate"]
            rounds = " -> ".join(f"{a['first']} (r = {a['corr_with_true_heat']:.2f}, {a['mean_power_w']:.0f} W)"
                                 for a in r.get("alternation") or [])
            hw = r.get("heat_w") or {}
            fitted = "-" if hw.get("fitted_mean_w") is None else f"{hw['fitted_mean_w']:.0f}"
            heat = (f"; the named source's mean heat {fitted} / {hw['calibrated_mean_w']:.0f} W" if hw else "")
            ratio_note = (f" (estimated heat {e['mean_power_w']:.0f} W mean against {e['true_mean_power_w']:.0f} W, "
                          f"r = {e['corr_with_true_heat']:.2f}; rounds: {rounds}{heat})")
        else:
            ratio_note = ""
        ident = {True: "identifiable", False: "not identifiable", None: "-"}[r.get("identifiable")]
        L.append(f"| {r['mechanism']} ({ident}) | {r['recording']}{ratio_note} | {ratio:.3f} | {r['first']} | {'yes' if r['effect_ok'] else 'no'} "
                 f"| {'yes' if r['target_ok'] else 'no'} | {par} | {rest} | {exp} "
                 f"| {', '.join(r.get('indistinguishable') or []) or '-'} "
                 f"| {', '.join(f'{c} {x:.2f}' for c, x in r.get('most_changed', []))} |")
    return "\n".join(L)


if __name__ == "__main__":
    import json
    import sys
    # python -m thermal_eval.fl_thermal.ablation [twin] [case indices, e.g. 0,3,8] [bearing|rule|all]
    only = [int(x) for x in sys.argv[2].split(",")] if len(sys.argv) > 2 and sys.argv[2] else None
    out = run(twin=sys.argv[1] if len(sys.argv) > 1 else "fl-thermal-rig", only=only,
              speedless=sys.argv[3] if len(sys.argv) > 3 else "bearing")
    print(screen_markdown(out["screen"]))
    print(markdown(out))
    print(json.dumps(out, indent=1, default=str))
