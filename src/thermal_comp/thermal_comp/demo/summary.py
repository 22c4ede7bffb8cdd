"""Evaluation of a demo run: uncompensated versus compensated P99 per error component, beside
the thesis's tables, as ``summary.json`` and a console table.

How "compensated" is computed: during [t_k, t_k+1) the CNC holds the offsets derived from the
prediction for t_k, so the error left on a part at t_k+1 is the true error at t_k+1 minus that
prediction (in component space). The bridge's limits are reported separately.
"""
from __future__ import annotations

import pathlib
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from thermal_comp.demo.cell import MACHINES, DemoConfig, plant_label
from thermal_comp.demo.graph import RunRecord
from thermal_comp.demo.series import DemoSeries
from thermal_comp_common import metrics, plain_output
from thermal_comp_common.probe_and_hold import TABLE_5_4_RESOLUTION_UM, probe_and_hold, table_5_4_noise

#: Published results the demo is compared with (Blaser thesis, Tables 6.5 and 6.7; P99).
THESIS_TABLES = {
    "talc-178h-dry": {
        "title": "thesis Table 6.5 (178 h, dry)",
        "p99_uncompensated": {"E_X0C": 4.4, "E_Y0C": 24.4, "E_Z0T": 27.5, "E_R0T": 8.5,
                              "E_A0C": 18.8, "E_B0C": 6.3, "E_C0C": 9.4},
        "p99_compensated": {"E_X0C": 2.7, "E_Y0C": 4.9, "E_Z0T": 6.1, "E_R0T": 2.9,
                            "E_A0C": 7.2, "E_B0C": 5.6, "E_C0C": 7.0},
    },
    "talc-144h-mwf": {
        "title": "thesis Table 6.7 (144 h, MWF)",
        "p99_uncompensated": {"E_Y0C": 43.4, "E_Z0T": 42.1},
        "p99_compensated": {"E_Y0C": 5.1},
    },
}


def compensation_in_effect(series: DemoSeries) -> dict[str, np.ndarray]:
    """Per ground-truth instant, the compensation the CNC held: the applied (read-back)
    values of the latest offsets stamped strictly before that instant when the CNC holds
    components (kinematic mode), else the latest prediction; zero before the first."""
    if series.applied:
        stamps, source = series.t_applied, series.applied
    else:
        stamps, source = series.t_pred, series.predicted
    idx = np.searchsorted(stamps, series.t_true, side="left") - 1
    out = {}
    for c in series.components:
        p = source[c]
        vals = np.where(idx >= 0, p[np.clip(idx, 0, None)] if p.size else 0.0, 0.0)
        out[c] = np.where(np.isfinite(vals), vals, 0.0)
    return out


def evaluation_start_s(series: DemoSeries) -> float:
    """Start of the compensation period: the first instant the model left its calibration
    phase (the thesis evaluates compensation after the calibration phase; during it nothing
    is compensated). The whole run if the model never left calibration."""
    for t, phase in series.phases:
        if phase != 0:
            return t
    return float(series.t_true[0])


def whole_run_and_baseline(series: DemoSeries, comp: dict[str, np.ndarray], q_prod_pct: float,
                           seed: int) -> dict[str, Any]:
    """P99 over the WHOLE run (calibration phase included: nothing compensated there) and the
    probe-and-hold baseline at the run's Q_prod over the same instants (Table 5.4 probe)."""
    out: dict[str, Any] = {"p99_compensated_whole_run": {}, "probe_and_hold": None}
    for c in series.components:
        ok = np.isfinite(series.true[c])
        if ok.any():
            out["p99_compensated_whole_run"][c] = round(metrics.p99(series.true[c][ok], comp[c][ok]), 3)
    if np.isfinite(q_prod_pct) and 0 <= q_prod_pct < 100 and series.t_true.size > 1:
        base = probe_and_hold(series.t_true, series.true, q_prod_pct, table_5_4_noise(series.components),
                              TABLE_5_4_RESOLUTION_UM, probe_duration_s=metrics.PROBE_CYCLE_DURATION_S, seed=seed)
        out["probe_and_hold"] = {"interval_h": round(base["interval_h"], 3),
                                 "p99": {c: round(v["p99"], 3) for c, v in base["components"].items()},
                                 "p99_lin_um": round(base["p99_lin_um"], 3),
                                 "p99_ang_um_per_m": round(base["p99_ang_um_per_m"], 3)}
    lin = [c for c in out["p99_compensated_whole_run"] if series.units.get(c) == "um"]
    out["p99_lin_whole_run_um"] = round(metrics.p99_group(out["p99_compensated_whole_run"], lin), 3)
    return out


def summarise(series: DemoSeries, cfg: DemoConfig, record: RunRecord | None) -> dict[str, Any]:
    comp = compensation_in_effect(series)
    t_eval = evaluation_start_s(series)
    window = series.t_true >= t_eval
    errors = {}
    for c in series.components:
        e = series.true[c]
        ok = np.isfinite(e) & window
        if not ok.any():
            continue
        unc = metrics.p99(e[ok], np.zeros(ok.sum()))
        cmp_ = metrics.p99(e[ok], comp[c][ok])
        errors[c] = {"unit": series.units[c], "p99_uncompensated": round(unc, 3), "p99_compensated": round(cmp_, 3),
                     "reduction_pct": round(100.0 * (1.0 - cmp_ / unc), 1) if unc > 0 else None}
    hours = float(series.t_true[-1] - series.t_true[0]) / 3600.0
    summary = {
        "machine": cfg.machine, "scenario": cfg.scenario, "seed": cfg.seed, "simulated_hours": round(hours, 2),
        "evaluation_window_h": [round(t_eval / 3600.0, 2), round(float(series.t_true[-1]) / 3600.0, 2)],
        "model_kind": series.status.get("model_kind", MACHINES[cfg.machine]["model_kind"]),
        "errors": errors,
        "probing_cycles": series.status.get("probing_cycles", len(series.probe_times_s)),
        "failed_probing_cycles": series.status.get("failed_probing_cycles", 0),
        "no_good_phases": series.status.get("no_good_phases", 0),
        "parameter_updates": series.status.get("parameter_updates", 0),
        "q_prod_pct": round(series.status.get("q_prod_pct", float("nan")), 2),
        "offsets_limited_steps": series.limit_hits, "offsets_published": series.offsets_published,
        "plant": plant_label(cfg), "prior": cfg.prior,
    }
    summary.update(whole_run_and_baseline(series, comp, summary["q_prod_pct"], cfg.seed))
    if record is not None and record.wall_s > 0:
        summary["wall_time_s"] = round(record.wall_s, 1)
        summary["times_real_time"] = round(record.sim_end_s / record.wall_s, 1)
    if cfg.scenario in THESIS_TABLES:
        summary["thesis"] = THESIS_TABLES[cfg.scenario]
    return summary


def _console() -> Console:
    """The terminal's console; piped or logged output gets wide tables and whole text lines, so
    the table's nine columns are not squeezed into 80 and no sentence is broken over lines."""
    return plain_output.console()


def print_table(summary: dict[str, Any]) -> None:
    thesis = summary.get("thesis", {})
    w0, w1 = summary["evaluation_window_h"]
    base = summary.get("probe_and_hold")
    t = Table(title=f"{summary.get('plant', summary['machine'])} / {summary['scenario']}: P99 of the thermal "
                    f"errors, {summary['model_kind'].upper()}"
                    f"{' with the prior ' + pathlib.Path(summary['prior']).name if summary.get('prior') else ' (no prior)'}, "
                    f"{summary['simulated_hours']} h simulated (compensated: {w0:g}-{w1:g} h, after the "
                    f"calibration phase; whole run: from 0 h)")
    t.add_column("error")
    t.add_column("unit")
    t.add_column("uncompensated", justify="right")
    t.add_column("compensated", justify="right")
    t.add_column("reduction", justify="right")
    t.add_column("comp. whole run", justify="right")
    if base:
        t.add_column(f"probe-and-hold (every {base['interval_h']:.2f} h)", justify="right")
    if thesis:
        t.add_column(f"{thesis['title']}: uncomp. / comp.", justify="right")
    for c, e in summary["errors"].items():
        row = [c, e["unit"], f"{e['p99_uncompensated']:.1f}", f"{e['p99_compensated']:.1f}",
               f"{e['reduction_pct']:.0f} %" if e["reduction_pct"] is not None else "-"]
        whole = summary.get("p99_compensated_whole_run", {}).get(c)
        row.append(f"{whole:.1f}" if whole is not None else "-")
        if base:
            row.append(f"{base['p99'][c]:.1f}" if c in base["p99"] else "-")
        if thesis:
            u = thesis["p99_uncompensated"].get(c)
            k = thesis["p99_compensated"].get(c)
            row.append(f"{u if u is not None else '-'} / {k if k is not None else '-'}")
        t.add_row(*row)
    c = _console()
    c.print(t)
    c.print(f"probing cycles {summary['probing_cycles']} (failed {summary['failed_probing_cycles']}), "
            f"no-good phases {summary['no_good_phases']}, parameter updates {summary['parameter_updates']}, "
            f"Q_prod {summary['q_prod_pct']} %"
            + (f"; thesis (§6.4.2): 4 no-good events from E_Y0C, 4 from E_Z0T, Q_prod about 97 % at the end"
               if summary["scenario"] == "talc-178h-dry" else ""))
    if base:
        ratio = summary["p99_lin_whole_run_um"] / base["p99_lin_um"] if base["p99_lin_um"] else float("nan")
        c.print(f"whole run P99_lin {summary['p99_lin_whole_run_um']} um; probe-and-hold at the same Q_prod "
                f"(no model, Table 5.4 probe): P99_lin {base['p99_lin_um']} um; ratio {ratio:.2f} (goal <= 0.5)")
    if "wall_time_s" in summary:
        c.print(f"wall time {summary['wall_time_s']} s ({summary['times_real_time']} x real time)")


def prior_gain(with_prior: dict[str, Any], no_prior: dict[str, Any], first_h: float = 24.0) -> dict[str, Any]:
    """Whole-run P99 per component with and without the prior (same plant, same scenario), the
    thesis's Table 6.5 beside them where the scenario has one, and the runs' Q_prod."""
    thesis = with_prior.get("thesis", {}).get("p99_compensated", {})
    rows = {}
    for c, v in with_prior.get("p99_compensated_whole_run", {}).items():
        rows[c] = {"with_prior": v, "no_prior": no_prior.get("p99_compensated_whole_run", {}).get(c),
                   "thesis": thesis.get(c)}
    return {"components": rows, "q_prod_pct": [with_prior["q_prod_pct"], no_prior["q_prod_pct"]],
            "p99_lin_whole_run_um": [with_prior["p99_lin_whole_run_um"], no_prior["p99_lin_whole_run_um"]],
            "no_good_phases": [with_prior["no_good_phases"], no_prior["no_good_phases"]]}


def print_prior_gain(with_prior: dict[str, Any], no_prior: dict[str, Any]) -> None:
    """The gain of the prior: whole-run P99 with and without it, beside Table 6.5."""
    g = prior_gain(with_prior, no_prior)
    t = Table(title=f"{with_prior.get('plant', with_prior['machine'])} / {with_prior['scenario']}: whole-run P99 "
                    "with the machine type's prior and without it (the thesis's protocol), same plant")
    for name in ("error", "with prior", "no prior", "thesis Table 6.5 (comp.)"):
        t.add_column(name, justify="left" if name == "error" else "right")

    def cell(v) -> str:
        return f"{v:.1f}" if isinstance(v, (int, float)) and np.isfinite(v) else "-"
    for c, r in g["components"].items():
        t.add_row(c, cell(r["with_prior"]), cell(r["no_prior"]), cell(r["thesis"]))
    t.add_row("P99_lin (um)", *(cell(v) for v in g["p99_lin_whole_run_um"]), "")
    thesis_run = with_prior["scenario"] == "talc-178h-dry"          # §6.4.2 gives these for that run
    t.add_row("Q_prod (%)", *(f"{v:.2f}" for v in g["q_prod_pct"]), "about 97" if thesis_run else "-")
    t.add_row("no-good phases", *(str(v) for v in g["no_good_phases"]), "8" if thesis_run else "-")
    _console().print(t)
