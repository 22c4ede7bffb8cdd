"""The tables of docs/twin_init.md, generated from ``bench twin-init``'s ``twin_init.json``:
``python -m thermal_eval.twin_init.report PATH/twin_init.json``; with a second JSON of the same
units run on other code, ``... AFTER.json BEFORE.json`` prints the two side by side."""
from __future__ import annotations

import json
import math
import pathlib
import sys

INIT = "init-twin prior from 24 h"
NO_PRIOR = "no prior running on"
TYPE = "type prior running on (needs the preset)"
LINEAR = ("E_X0C", "E_Y0C", "E_Z0T", "E_R0T")


def _f(v, digits: int = 3) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{digits}f}"


def units_table(units: list[dict]) -> list[str]:
    lines = ["| unit | what differs (hidden from twin init) | hidden bodies | probes day 1 | no prior running on "
             "| **init-twin prior from 24 h** | type prior (needs the preset) | init P99 " + "/".join(LINEAR) + " um |",
             "|---|---|---|---|---|---|---|---|"]
    for u in units:
        r = u["ratios"]
        comps = u["components_p99"][INIT]
        lines.append(f"| #{u['seed']} {u['kind']} | {u['truth']} | {u['hidden_bodies']} | {u['probes_first_day']} | "
                     f"{_f(r[NO_PRIOR])} | **{_f(r[INIT])}** | {_f(r.get(TYPE))} | "
                     + " / ".join(_f(comps[c], 2) for c in LINEAR) + " |")
    return lines


def held_out_table(units: list[dict]) -> list[str]:
    """Open-loop held-out RMSE of the twin chosen on 0-18 h, on the probes of 18-24 h."""
    chans = list(LINEAR) + ["E_A0C", "E_B0C", "E_C0C"]
    lines = ["| unit | predictor | " + " | ".join(chans) + " |", "|---|---|" + "---|" * len(chans)]
    for u in units:
        h = u["init_held_out_rmse"]
        for name in ("twin", "training mean", "static regression"):
            lines.append(f"| #{u['seed']} {u['kind']} | {name} | " + " | ".join(_f(h[c][name], 2) for c in chans) + " |")
    return lines


def adoption_table(rows: list[dict]) -> list[str]:
    names = ("no prior running on", "init-twin prior from 48 h, always", "init-twin prior from 48 h if adopted")
    lines = ["| unit | hidden bodies | adopted at 48 h | why | " + " | ".join(names) + " |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| #{r['seed']} {r['kind']} | {r['hidden_bodies']} | {'yes' if r['adopted'] else 'no'} | "
                     f"{r['reason']} | " + " | ".join(_f(r['ratios'][n]) for n in names) + " |")
    return lines


def fl_table(fl: dict) -> list[str]:
    names = list(next(iter(fl["rows"].values())))
    lines = ["| channel | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for ch, row in fl["rows"].items():
        lines.append(f"| {ch} | " + " | ".join(f"{_f(row[n]['test_mae_um'])} [{_f(row[n]['validation_mae_um'])}]"
                                               for n in names) + " |")
    return lines


def fl_adaptive_table(ad: dict) -> list[str]:
    """Per channel: the twin row's adaptive phase-mean MAE beside the data-only rows and baselines."""
    best = ad["best data-only row"]
    cols = ["twin adaptive", f"best data-only adaptive ({best})", "best data-only adaptive of the channel",
            "holding", "twin open loop", "lagged ridge open loop", "training mean", "static regression"]
    heads = ["**twin soft sensors, adaptive**", f"evaluate's best data-only adaptive row (`{best}`)",
             "best data-only adaptive row of the channel", "holding the twin row's probes", "twin soft sensors, open loop",
             "lagged ridge, open loop", "training mean", "static regression"]
    lines = ["| channel | " + " | ".join(heads) + " |", "|---|" + "---|" * len(heads)]
    for ch, r in ad["channels"].items():
        cells = [f"{_f(r[c][0])} [{_f(r[c][1])}]" if r.get(c) else "n/a" for c in cols]
        cells[0] = f"**{cells[0]}**"
        cells[2] += f" `{r['best of the channel']}`"
        lines.append(f"| {ch} | " + " | ".join(cells) + " |")
    n = len(ad["channels"])
    for ref, what in (("better_than_best_row", f"evaluate's best data-only adaptive row (`{best}`)"),
                      ("better_than_best_of_each_channel", "the best data-only adaptive row of each channel")):
        w = ad[ref]
        lines += ["", f"- twin row below {what} on {w['mean_of_windows']} of {n} channels (mean of the two windows), "
                      f"{w['test']} of {n} on the test rows, {w['validation']} of {n} on the validation rows."]
    lines += ["", "- channels (mean of the two windows) on which the twin row is below each data-only row: "
              + ", ".join(f"`{k}` {v}" for k, v in ad["better_than_each_row"].items()) + "."]
    return lines


def summary(units: list[dict]) -> list[str]:
    init = [u["ratios"][INIT] for u in units]
    none = [u["ratios"][NO_PRIOR] for u in units]
    walls = [u["wall_s"]["twin_init"] for u in units]
    speed = [u["twin_simulated_h_per_s"] for u in units]
    return [f"- init-twin prior from 24 h: ratio {min(init):.3f}-{max(init):.3f} over {len(init)} units, "
            f"{sum(r <= 0.5 for r in init)} of {len(init)} at most 0.5 (target: every unit); "
            f"no prior running on {min(none):.3f}-{max(none):.3f}; better than no prior on "
            f"{sum(a < b for a, b in zip(init, none))} of {len(init)}.",
            f"- twin init wall time {min(walls):.1f}-{max(walls):.1f} s per unit (24 h at 60 s), "
            f"twin {min(speed):.0f}-{max(speed):.0f} simulated h/s in the fit."]


def before_after_table(after: list[dict], before: list[dict]) -> list[str]:
    """Per unit of ``after`` (matched by seed and kind): hidden bodies and the init-twin ratio before
    and after, beside the no-prior protocol of the same run; a summary line below."""
    old = {(u["seed"], u["kind"]): u for u in before}
    lines = ["| unit | hidden bodies before -> after | no prior running on | init-twin prior before | "
             "**init-twin prior after** | change |", "|---|---|---|---|---|---|"]
    pairs = []
    for u in after:
        b = old.get((u["seed"], u["kind"]))
        if b is None:
            continue
        r0, r1 = b["ratios"][INIT], u["ratios"][INIT]
        pairs.append((r0, r1, u["ratios"][NO_PRIOR]))
        lines.append(f"| #{u['seed']} {u['kind']} | {b['hidden_bodies']} -> {u['hidden_bodies']} | "
                     f"{_f(u['ratios'][NO_PRIOR])} | {_f(r0)} | **{_f(r1)}** | {r1 - r0:+.3f} |")
    if pairs:
        r0, r1, none = (list(x) for x in zip(*pairs))
        lines += ["", f"- {len(pairs)} units: before {min(r0):.3f}-{max(r0):.3f} (mean {sum(r0) / len(r0):.3f}, "
                      f"{sum(r <= 0.5 for r in r0)} at most 0.5), after {min(r1):.3f}-{max(r1):.3f} (mean "
                      f"{sum(r1) / len(r1):.3f}, {sum(r <= 0.5 for r in r1)} at most 0.5); better on "
                      f"{sum(a < b for a, b in zip(r1, r0))}, worse on {sum(a > b for a, b in zip(r1, r0))}; "
                      f"worse than no prior on {sum(a > n for a, n in zip(r1, none))}"]
    return lines


def markdown(doc: dict) -> str:
    out = []
    if doc.get("units"):
        out += ["### nmv5000 units without the preset (ratio to probe-and-hold over 24-178 h)", ""]
        out += units_table(doc["units"]) + [""] + summary(doc["units"]) + ["",
                "### The init twin open loop on the held-out probes of 18-24 h (RMSE, um or um/m)", ""]
        out += held_out_table(doc["units"])
    if doc.get("adoption"):
        out += ["", "### With the adoption test: the init-twin prior takes over at 48 h only if it predicted the "
                    "probes of 24-48 h better (ratio to probe-and-hold over 48-178 h)", ""] + adoption_table(doc["adoption"])
    if doc.get("fl_thermal"):
        fl = doc["fl_thermal"]
        out += ["", f"### FL_THERMAL: test [validation] MAE, um ({fl['hidden_bodies']} hidden bodies; "
                    f"twin init {fl['wall_s']} s, {fl['twin_simulated_h_per_s']} simulated h/s)", ""] + fl_table(fl)
        if fl.get("adaptive"):
            ad = fl["adaptive"]
            out += ["", f"### FL_THERMAL adaptive, <= 1 probing per hour ({max(ad['probings_per_h'].values()):.2f} "
                        f"at most, any row and phase): phase mean of the test [validation] MAE, um", ""]
            out += fl_adaptive_table(ad)
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    _doc = json.loads(pathlib.Path(sys.argv[1]).read_text())
    if len(sys.argv) > 2:
        _before = json.loads(pathlib.Path(sys.argv[2]).read_text())
        sys.stdout.write("\n".join(before_after_table(_doc["units"], _before["units"])) + "\n")
    else:
        sys.stdout.write(markdown(_doc))
