"""The online learner in the demo (``--learn-every-h H``): its node in the cell, and the table
before and after the first adoption: P99 per component and P99_lin against probe-and-hold (at the
run's Q_prod, probing over the whole run, scored on each side) on each side of the instant the
learned prior was swapped in, read from the learner's audit (talc_model.online). The learner
node itself is in the cell document (thermal_comp.demo.cell.learner_node).
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
from typing import Any

import numpy as np
from rich.table import Table

from talc_model.online.audit import read_audit
from thermal_comp.demo.cell import AUDIT
from thermal_comp.demo.series import DemoSeries, read_series
from thermal_comp.demo.summary import compensation_in_effect
from thermal_comp_common import metrics, plain_output
from thermal_comp_common.probe_and_hold import TABLE_5_4_RESOLUTION_UM, probe_and_hold, table_5_4_noise

def adoption_instant(audit: list[dict]) -> float | None:
    """Model time (s) of the first swap the model node audited (None: nothing was adopted)."""
    for line in audit:
        if line.get("event") == "swapped" and line.get("model_time_s") is not None:
            return float(line["model_time_s"])
    return None


def _side(series: DemoSeries, comp: dict, mask: np.ndarray, q_prod_pct: float, seed: int) -> dict[str, Any] | None:
    if mask.sum() < 2:
        return None
    p99 = {}
    for c in series.components:
        ok = mask & np.isfinite(series.true[c])
        if ok.any():
            p99[c] = round(metrics.p99(series.true[c][ok], comp[c][ok]), 3)
    lin = [c for c in p99 if series.units.get(c) == "um"]
    side = {"window_h": [round(float(series.t_true[mask][0]) / 3600.0, 2), round(float(series.t_true[mask][-1]) / 3600.0, 2)],
            "p99": p99, "p99_lin_um": round(metrics.p99_group(p99, lin), 3)}
    if math.isfinite(q_prod_pct) and 0 <= q_prod_pct < 100:
        base = probe_and_hold(series.t_true, series.true, q_prod_pct, table_5_4_noise(series.components),
                              TABLE_5_4_RESOLUTION_UM, window=mask, probe_duration_s=metrics.PROBE_CYCLE_DURATION_S,
                              seed=seed)
        side["probe_and_hold"] = {"p99": {c: round(v["p99"], 3) for c, v in base["components"].items()},
                                  "p99_lin_um": round(base["p99_lin_um"], 3)}
        side["ratio"] = round(side["p99_lin_um"] / base["p99_lin_um"], 3) if base["p99_lin_um"] else None
    return side


def split_at(series: DemoSeries, comp: dict, q_prod_pct: float, t_split_s: float, seed: int) -> dict[str, Any]:
    """Both sides of ``t_split_s`` (the first instant after it is the new model's)."""
    return {"before": _side(series, comp, series.t_true <= t_split_s, q_prod_pct, seed),
            "after": _side(series, comp, series.t_true > t_split_s, q_prod_pct, seed)}


def learning_summary(series: DemoSeries, comp: dict, q_prod_pct: float, out: pathlib.Path, seed: int) -> dict[str, Any]:
    """What the learner did (its audit) and, if a prior was swapped in, the table on both sides."""
    audit = read_audit(out / AUDIT)
    t_adopt = adoption_instant(audit)
    res: dict[str, Any] = {"audit": [{k: ln.get(k) for k in ("model_time_s", "source", "event", "decision", "reason",
                                                             "old_prior_sha256", "new_prior_sha256", "figures")}
                                     for ln in audit],
                           "adopted_at_h": None if t_adopt is None else round(t_adopt / 3600.0, 3)}
    if t_adopt is not None:
        res |= split_at(series, comp, q_prod_pct, t_adopt, seed)
    return res


def print_learning(summary: dict[str, Any]) -> None:
    """The learner's audit in short and the table before / after the first adoption."""
    learn = summary.get("learning")
    if not learn:
        return
    c = plain_output.console()
    for ln in learn["audit"]:
        t = ln.get("model_time_s")
        c.print(f"learner audit {'' if t is None else f'{t / 3600.0:.1f} h'} ({ln['source']}) {ln['event']}: {ln['reason']}")
    if learn.get("after") is None or learn.get("before") is None:
        c.print("no learned prior was swapped in during the run: the table above is the type's prior throughout")
        return
    b, a = learn["before"], learn["after"]
    tab = Table(title=f"{summary.get('plant', summary['machine'])}: P99 before and after the learned prior was "
                      f"swapped in at {learn['adopted_at_h']:g} h (probe-and-hold at Q_prod {summary['q_prod_pct']} %)")
    for name in ("error", f"before ({b['window_h'][0]:g}-{b['window_h'][1]:g} h)", "probe-and-hold before",
                 f"after ({a['window_h'][0]:g}-{a['window_h'][1]:g} h)", "probe-and-hold after"):
        tab.add_column(name, justify="left" if name == "error" else "right")
    for comp in b["p99"]:
        tab.add_row(comp, f"{b['p99'][comp]:.2f}", f"{b['probe_and_hold']['p99'][comp]:.2f}",
                    f"{a['p99'][comp]:.2f}", f"{a['probe_and_hold']['p99'][comp]:.2f}")
    tab.add_row("P99_lin (um)", f"{b['p99_lin_um']:.2f}", f"{b['probe_and_hold']['p99_lin_um']:.2f}",
                f"{a['p99_lin_um']:.2f}", f"{a['probe_and_hold']['p99_lin_um']:.2f}")
    tab.add_row("ratio to probe-and-hold", f"{b['ratio']:.3f}", "", f"{a['ratio']:.3f}", "")
    c.print(tab)


def markdown(summary: dict[str, Any], control: dict[str, Any] | None = None) -> str:
    """docs/learn.md's table from a learning run's summary.json (and, as the control, the
    ``learning`` split of a run of the same plant without the learner, made at the same instant)."""
    learn = summary["learning"]
    b, a = learn["before"], learn["after"]
    cb, ca = (control or {}).get("before"), (control or {}).get("after")
    head = ["error", f"before: {b['window_h'][0]:g}-{b['window_h'][1]:g} h", "probe-and-hold before",
            f"after: {a['window_h'][0]:g}-{a['window_h'][1]:g} h", "probe-and-hold after"]
    if ca:
        head += ["control after (type prior running on)"]
    rows = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for comp in b["p99"]:
        cells = [comp, b["p99"][comp], b["probe_and_hold"]["p99"][comp], a["p99"][comp],
                 a["probe_and_hold"]["p99"][comp]] + ([ca["p99"][comp]] if ca else [])
        rows.append("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in cells) + " |")
    lin = ["P99_lin (um)", b["p99_lin_um"], b["probe_and_hold"]["p99_lin_um"], a["p99_lin_um"],
           a["probe_and_hold"]["p99_lin_um"]] + ([ca["p99_lin_um"]] if ca else [])
    rows.append("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in lin) + " |")
    ratio = ["**ratio to probe-and-hold**", f"**{b['ratio']:.3f}**", "", f"**{a['ratio']:.3f}**", ""]
    rows.append("| " + " | ".join(ratio + ([f"**{ca['ratio']:.3f}**"] if ca else [])) + " |")
    if cb:
        rows.append("")
        rows.append(f"Control before the same instant: ratio {cb['ratio']:.3f} (P99_lin {cb['p99_lin_um']:.2f} um).")
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    """``python -m thermal_comp.demo.learning SUMMARY.json [CONTROL_OUT]``: the markdown table;
    CONTROL_OUT is the output folder of a demo of the same plant without the learner, split at
    the learning run's first swap."""
    ap = argparse.ArgumentParser(prog="python -m thermal_comp.demo.learning", description=main.__doc__)
    ap.add_argument("summary")
    ap.add_argument("control_out", nargs="?")
    a = ap.parse_args(argv)
    summary = json.loads(pathlib.Path(a.summary).read_text())
    control = None
    if a.control_out:
        series = read_series(pathlib.Path(a.control_out) / "bag")
        ctrl = json.loads((pathlib.Path(a.control_out) / "summary.json").read_text())
        control = split_at(series, compensation_in_effect(series), ctrl["q_prod_pct"],
                           summary["learning"]["adopted_at_h"] * 3600.0, summary["seed"])
    print(markdown(summary, control), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
