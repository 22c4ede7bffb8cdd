"""Where the mismatch finder (``thermal-comp diagnose``, thermal_twin.diagnose.locate) locates the
unit's difference from a twin, beside learn's own words: the time windows where a channel's
residual stands out and the operating regimes whose residual differs, computed by the finder's
own functions on what a cell records (the probe instants of the fit window: the probed errors
and the temperatures there), for the twin learn started from and for the learned one (what is
left). The finder's effect search (its library of named physics, about a minute per recording)
is not run inside learn. No rclpy.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_twin.diagnose.locate import locate_windows, operating_regimes, regime_effects
from thermal_twin.machine.schema import Machine

#: windows and regime effects kept per twin in the report
KEEP = 5
#: a regime effect is reported from this size relative to the channel's residual RMS
MIN_RELATIVE = 0.5


def _residuals(machine: Machine, outputs: dict, rec: Recording, rows: np.ndarray, components: list[str]) -> dict:
    fed = {s.from_sensor for s in machine.inputs.values() if s.from_sensor}   # read backwards: no residual
    chans = [s.column for n, s in machine.sensors.items() if s.column in rec.columns and n not in fed] + components
    out = {}
    for c in chans:
        r = np.asarray(rec.columns[c], float)[rows] - np.asarray(outputs[c], float)[rows]
        if np.isfinite(r).sum() >= 3:
            out[c] = r
    return out


def located(machine: Machine, outputs: dict[str, dict], rec: Recording, components: list[str],
            fit_until_s: float) -> dict[str, Any]:
    """Per twin (``outputs``: name -> its outputs on ``rec``'s rows): the finder's located windows
    and regime effects of the residuals at the probe instants up to ``fit_until_s``."""
    probed = np.any([np.isfinite(np.asarray(rec.columns[c], float)) for c in components], axis=0)
    rows = np.flatnonzero(probed & (rec.time_s <= fit_until_s))
    if rows.size < 6:
        return {"note": f"{rows.size} probe instants in the fit window: too few to locate anything"}
    t = rec.time_s[rows]
    # the machine's drivers (speed, coolant on): a temperature input is no regime
    inputs = {n: np.asarray(rec.columns[n], float)[rows] for n, s in machine.inputs.items()
              if n in rec.columns and s.unit != "degC"}
    regimes = operating_regimes(t - t[0], inputs)
    units = {c: machine.errors[c].unit if c in machine.errors else "degC" for c in
             [s.column for s in machine.sensors.values()] + components}
    report: dict[str, Any] = {"instants": int(rows.size),
                              "what": "located windows and regime effects (thermal_twin.diagnose.locate) of the "
                                      "residuals at the probe instants of the fit window"}
    for name, out in outputs.items():
        res = _residuals(machine, out, rec, rows, components)
        windows = sorted(locate_windows(t, res, regimes, units), key=lambda w: -max(
            abs(e["value"]) for e in w["effect"].values()))[:KEEP]
        effects = [e for e in regime_effects(res, regimes, units) if e["relative"] >= MIN_RELATIVE][:KEEP]
        report[name] = {"windows": windows, "regime_effects": effects}
    return report


def finder_markdown(rep: dict[str, Any] | None) -> list[str]:
    """report.md's section on what the finder locates (empty without it)."""
    if not rep:
        return []
    lines = ["", "## Where the mismatch finder locates it", ""]
    if "note" in rep:
        return lines + [rep["note"]]
    lines += [f"The finder's own functions: {rep['what']} ({rep['instants']} instants). Its search of named "
              "physics is not run here; learn's words above are learn's answer.", ""]
    for name in (k for k in rep if isinstance(rep[k], dict)):
        lines.append(f"- **{name}**:")
        for w in rep[name]["windows"]:
            eff = ", ".join(f"{c} {e['value']:+.3g} {e['unit']}" for c, e in w["effect"].items())
            lines.append(f"  - window {w['start_s'] / 3600.0:.1f}-{w['end_s'] / 3600.0:.1f} h ({w['regime']}): {eff}")
        for e in rep[name]["regime_effects"]:
            lines.append(f"  - regime {e['regime']}: {e['channel']} {e['effect']:+.3g} {e['unit']} inside vs outside "
                         f"({e['relative']:.2f} x its residual RMS)")
        if not rep[name]["windows"] and not rep[name]["regime_effects"]:
            lines.append("  - nothing stands out")
    return lines
