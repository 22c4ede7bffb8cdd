"""report.md of a several-run ``learn``, every figure taken from its report.json. No rclpy."""
from __future__ import annotations

from typing import Any, Mapping

from thermal_eval.learn.report_text import fmt, tested_against_lines


def _table(title: str, scores: Mapping[str, Any]) -> list[str]:
    """RMSE (and n) per predictor and component."""
    comps = list(next(iter(scores.values()))) if scores else []
    lines = ["", title, "", "| predictor | " + " | ".join(comps) + " |", "|---" * (len(comps) + 1) + "|"]
    for name, row in scores.items():
        lines.append(f"| {name} | " + " | ".join(fmt(row[c]["rmse"]) for c in comps) + " |")
    return lines


def _words(st: Mapping[str, Any] | None) -> list[str]:
    if st is None:
        return ["Words: not searched.", ""]
    lines = ["## What was added", ""]
    lines += [f"- {w['what']} (fit cost {w['fit_cost']:.3g} of the calibrated twin's; validation: "
              f"{w['validation']['reason']})" for w in st["words"]] or [
        "Nothing: no word was better on the validation probes than the calibrated twin."]
    return lines + ["", f"{len(st['tried'])} words tried in {st['wall_s']} s; {st['note']}.", ""]


def runs_markdown(rep: Mapping[str, Any]) -> str:
    """report.md of :func:`thermal_eval.learn.runs.command.learn_runs`'s report."""
    lines = [f"# Learning the unit: {rep['twin']} from {len(rep['runs'])} runs", "",
             f"Split `{rep['split']}`; the adoption is decided on {rep['validation_rule']}. Calibration "
             f"{rep['wall_s']['calibration']} s, twin {rep['twin_simulated_h_per_s']} simulated h/s.", "",
             "| run | role | unit | programme | date | hours | probes | fitted up to h | validation probes "
             "| scored probes |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rep["runs"]:
        lines.append(f"| {r['name']} | {r['role']} | {r['unit'] or '-'} | {r['programme'] or '-'} | "
                     f"{r['date'] or '-'} | "
                     f"{r['hours']:.2f} | {r['probes']} | {fmt(r['fitted_until_h'])} | {r['validation_probes']} | "
                     f"{r['scored_probes']} |")
    lines += ["", f"**{'Adopted' if rep['adoption']['adopt'] else 'Not adopted'}**: {rep['adoption']['reason']}.", "",
              *tested_against_lines(rep.get("tested_against")), *_words(rep.get("structure")),
              "## What moved", "", "| parameter | start | learned | change | at tolerance bound |",
              "|---|---|---|---|---|"]
    for p in rep["parameters"]:
        lines.append(f"| {p['name']} | {fmt(p['start'])} {p['unit']} | {fmt(p['value'])} | "
                     f"{fmt(p['change_pct'])} % | {'yes' if p['at_bound'] else ''} |")
    pooled = rep["scores"]["pooled"]
    for role in ("test", "validation", "train"):
        if role in pooled:
            what = {"test": "the test runs (never fitted, never decided on)", "validation": "the validation runs",
                    "train": "the training runs' validation windows"}[role]
            lines += _table(f"## Pooled over {what}: RMSE of probe - prediction, made before the probe",
                            pooled[role])
    if rep.get("folds"):
        lines += ["", "## Folds: each learning scored on the runs it held out", "",
                  "| fold | trained on | held out | adopted | folder |", "|---|---|---|---|---|"]
        lines += [f"| {f['name']} | {', '.join(f['train'])} | {', '.join(f['test'])} | "
                  f"{'yes' if f['adopt'] else 'no'} | "
                  f"`{f['dir']}` |" for f in rep["folds"]]
        lines += _table("## Pooled over the folds' held-out runs: RMSE of probe - prediction", rep["pooled_over_folds"])
    for name, scores in rep["scores"]["per_run"].items():
        lines += _table(f"### Run {name}", scores)
    lines += ["", "Units: um (E_A0C, E_B0C, E_C0C: um/m). The probe noise is part of every figure alike.", "",
              "## Files", ""] + [f"- {k}: `{v}`" for k, v in rep["files"].items()]
    return "\n".join(lines) + "\n"
