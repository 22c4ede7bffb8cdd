"""The calibration report: ``report.json``, ``report.md`` and PNG plots of a
:class:`~thermal_twin.calibrate.fit.CalibrationResult` (matplotlib, Agg backend)."""
from __future__ import annotations

import json
import math
import pathlib

import numpy as np

from thermal_twin.calibrate.fit import CORR_LIMIT, CalibrationResult, left_out_lines
from thermal_twin.calibrate.runs import SPREAD_SHARE, FoldsCalibration


def report_dict(r: CalibrationResult, twin: str, recording: str, notes: list[str],
                input_estimates: list[dict] | None = None, runs: list[dict] | None = None,
                folds: FoldsCalibration | None = None) -> dict:
    """The report's content; ``runs`` (several recordings): every run's own figures, and then
    ``r`` holds the runs laid end to end, so its channel table is the pooled one. ``folds``
    with several folds: ``r`` is the fit on all runs (written), its held-out figures are those
    pooled over the folds, and ``folds`` carries every fold's figures and the parameters' spread."""
    held = r.n_train < len(r.time_s)
    rep = {
        "twin": twin, "recording": recording,
        "split": {"train_end_s": float(r.time_s[r.n_train - 1]),
                  "holdout_start_s": float(r.time_s[r.n_train]) if held else None, "end_s": float(r.time_s[-1])},
        "channels": r.channel_table(),
        "parameters": [e.as_dict() for e in r.estimates],
        "not_identified": [e.param.name for e in r.estimates if any(f.startswith("not identified") for f in e.flags)],
        "correlated_pairs": [{"a": a, "b": b, "corr": c} for a, b, c in r.correlated],
        "correlated_pairs_limit": CORR_LIMIT,
        "fixed": r.fixed,
        "left_out": r.left_out_counts(),
        "fit": {"cost_before": r.cost_before, "cost_after": r.cost_after, "status": r.status,
                "twin_evaluations": r.n_evals, "wall_s": r.wall_s, "simulated_h": r.simulated_h,
                "simulated_h_per_s": r.simulated_h / max(r.wall_s, 1e-9),
                "residual_autocorrelation_time_samples": r.tau},
        "calibrated_twin": "twin_calibrated.yaml",
        "input_estimates": input_estimates or [],
        "notes": notes,
    }
    if runs:
        rep["runs"] = runs
        rep["split"]["by_run"] = {"train": [x["name"] for x in runs if x["role"] == "train"],
                                  "holdout": [x["name"] for x in runs if x["role"] == "holdout"]}
        if any(x["role"] == "validation" for x in runs):
            rep["split"]["by_run"]["validation"] = [x["name"] for x in runs if x["role"] == "validation"]
    if folds is not None:
        rep["split"]["fold"] = folds.written_from         # the split's name, or 'all runs' with several folds
    if folds is not None and len(folds.folds) > 1:
        rep["folds"] = {"n_folds": len(folds.folds), "written": folds.written_from, "folds": folds.folds,
                        "pooled_held_out": folds.pooled, "parameter_spread": folds.spread,
                        "spread_share_limit": SPREAD_SHARE, "n_parameters": len(folds.spread),
                        "moving_parameters": [p["name"] for p in folds.spread if p["moves"]]}
        rep["folds"]["n_moving"] = len(rep["folds"]["moving_parameters"])
        for c, v in rep["channels"].items():
            v["holdout_rmse_before"] = folds.pooled[c]["rmse_before"]
            v["holdout_rmse_after"] = folds.pooled[c]["rmse_after"]
    return rep


def _num(v, nd=4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float) and not math.isfinite(v):
        return "inf" if v > 0 else "-inf"
    return f"{v:.{nd}g}"


def write_markdown(rep: dict, out: pathlib.Path) -> pathlib.Path:
    f = rep["fit"]
    by_run = rep["split"].get("by_run")
    split = (f"Written: the fit on all runs ({', '.join(by_run['train'])}); its held-out figures are those of "
             f"the {rep['folds']['n_folds']} folds below, each run scored by the fit that did not see it. "
             if "folds" in rep else f"Training runs {', '.join(by_run['train'])}; held out {', '.join(by_run['holdout'])} (every run "
             "simulated from its own initial state; the held-out runs are not fitted, figures pooled over "
             "each role's runs). " if by_run else
             f"Training 0 .. {rep['split']['train_end_s'] / 3600:.2f} h, held out "
             f"{rep['split']['holdout_start_s'] / 3600:.2f} .. {rep['split']['end_s'] / 3600:.2f} h. ")
    lines = [f"# Calibration of {rep['twin']} on {rep['recording']}", "",
             split + f"Noise-weighted cost (training) {f['cost_before']:.4g} -> {f['cost_after']:.4g}; "
             f"{f['twin_evaluations']} twin evaluations, {f['wall_s']:.1f} s wall, "
             f"{f['simulated_h_per_s']:.0f} simulated h/s; optimiser: {f['status']}", "",
             "## Held-out RMSE per channel", "",
             "| channel | train before | train after | held-out before | held-out after |",
             "| --- | --- | --- | --- | --- |"]
    for c, v in rep["channels"].items():
        lines.append(f"| {c} | {_num(v['train_rmse_before'])} | {_num(v['train_rmse_after'])} | "
                     f"{_num(v['holdout_rmse_before'])} | {_num(v['holdout_rmse_after'])} |")
    lines += _runs_markdown(rep.get("runs") or [])
    lines += _folds_markdown(rep["folds"]) if "folds" in rep else []
    lines += ["", "## Parameters", "",
              "95 % intervals from the Jacobian, inflated by the residual's autocorrelation time "
              f"({f['residual_autocorrelation_time_samples']:.0f} fitted samples).", "",
              "| parameter | unit | start | estimate | 95 % interval | bounds | flags |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for p in rep["parameters"]:
        lines.append(f"| {p['name']} | {p['unit']} | {_num(p['start'])} | {_num(p['value'])} | "
                     f"{_num(p['ci95'][0])} .. {_num(p['ci95'][1])} | {_num(p['bounds'][0])} .. "
                     f"{_num(p['bounds'][1])} | {', '.join(p['flags'])} |")
    if rep["not_identified"]:
        lines += ["", f"**Not identified by this recording** ({len(rep['not_identified'])}): "
                  + ", ".join(rep["not_identified"])]
    if rep["correlated_pairs"]:
        lines += ["", f"**Correlated pairs** (|corr| > {rep['correlated_pairs_limit']}; only their combination "
                  "is determined):", ""]
        lines += [f"- {x['a']} / {x['b']}: {x['corr']:+.3f}" for x in rep["correlated_pairs"][:30]]
        if len(rep["correlated_pairs"]) > 30:
            lines.append(f"- ... {len(rep['correlated_pairs']) - 30} more in report.json")
    if rep["fixed"]:
        lines += ["", "Left fixed: " + "; ".join(rep["fixed"])]
    if rep["left_out"]:
        lines += ["", "**Readings left out of the fit and of every figure:**", ""]
        lines += [f"- {x}" for x in left_out_lines(rep["left_out"])]
    if rep["notes"]:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in rep["notes"]]
    lines += ["", "![channels](channels.png)", "", "![parameters](parameters.png)", ""]
    p = out / "report.md"
    p.write_text("\n".join(lines))
    return p


def _runs_markdown(runs: list[dict]) -> list[str]:
    """Every run's RMSE per channel, before -> after."""
    if not runs:
        return []
    chans = list(runs[0]["channels"])
    lines = ["", "## RMSE per run (before -> after)", "", "| run | role | h | " + " | ".join(chans) + " |",
             "| --- | --- | --- |" + " --- |" * len(chans)]
    for x in runs:
        cells = [f"{_num(x['channels'][c]['rmse_before'], 3)} -> {_num(x['channels'][c]['rmse_after'], 3)}"
                 for c in chans]
        lines.append(f"| {x['name']} | {x['role']} | {x['hours']:.1f} | " + " | ".join(cells) + " |")
    return lines


def _folds_markdown(fo: dict) -> list[str]:
    """Every fold (its runs and pooled held-out RMSE), every held-out run from the fold that held
    it out with the pooled row, and the parameters' spread across folds."""
    chans = list(fo["pooled_held_out"])
    arrow = lambda v, b, a: f"{_num(v[b], 3)} -> {_num(v[a], 3)}"
    lines = ["", f"## Folds ({fo['n_folds']}; held-out RMSE before -> after)", "",
             "| fold | fitted on | held out | s | " + " | ".join(chans) + " |",
             "| --- | --- | --- | --- |" + " --- |" * len(chans)]
    for f in fo["folds"]:
        lines.append(f"| {f['name']} | {', '.join(f['train'])} | {', '.join(f['held_out'])} | {f['wall_s']:.1f} | "
                     + " | ".join(arrow(f["channels"][c], "holdout_rmse_before", "holdout_rmse_after") for c in chans)
                     + " |")
    lines += ["", "## Held-out runs (each from the fold that held it out)", "",
              "| run | fold | " + " | ".join(chans) + " |", "| --- | --- |" + " --- |" * len(chans)]
    for f in fo["folds"]:
        for x in f["runs"]:
            if x["role"] != "train":
                lines.append(f"| {x['name']} | {f['name']} | "
                             + " | ".join(arrow(x["channels"][c], "rmse_before", "rmse_after") for c in chans) + " |")
    lines.append("| **pooled** | all folds | "
                 + " | ".join(arrow(fo["pooled_held_out"][c], "rmse_before", "rmse_after") for c in chans) + " |")
    lines += ["", "## Parameters across folds", "",
              f"{fo['n_moving']} of {fo['n_parameters']} parameters move by more than "
              f"{100 * fo['spread_share_limit']:.0f} % of their allowed range between folds (**moves**: not "
              "pinned down by these runs; its written value is one of many the data allow). 'disjoint': the "
              "folds' 95 % intervals share no value (each fold is sure of a different one).", "",
              "| parameter | unit | " + " | ".join(f["name"] for f in fo["folds"]) + " | written | moves (% of range) |",
              "| --- | --- |" + " --- |" * (len(fo["folds"]) + 2)]
    for p in fo["parameter_spread"]:
        flag = ("**moves** " if p["moves"] else "") + ("disjoint " if p["disjoint"] else "")
        lines.append(f"| {p['name']} | {p['unit']} | " + " | ".join(_num(v) for v in p["values"])
                     + f" | {_num(p['written'])} | {flag}{100 * p['share_of_range']:.1f} |")
    return lines


def plot_channels(r: CalibrationResult, path: pathlib.Path) -> None:
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    n = len(r.channels)
    cols = 3
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(15, 2.4 * rows), sharex=True, squeeze=False)
    th = r.time_s / 3600.0
    for ax, c in zip(axes.ravel(), r.channels):
        ax.plot(th, r.measured[c], "k", lw=0.8, label="recording")
        ax.plot(th, r.before[c], "r", lw=0.8, label="twin before")
        ax.plot(th, r.after[c], "b", lw=0.8, label="calibrated")
        if r.n_train < len(th):                 # the fit on all runs has no held-out part
            ax.axvspan(th[r.n_train], th[-1], color="0.9")
        ax.set_title(c, fontsize=9)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.supxlabel("time [h] (held-out part shaded)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_parameters(r: CalibrationResult, path: pathlib.Path) -> None:
    """Each estimate relative to its start value, with its 95 % interval clipped to the bounds."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    est = r.estimates
    fig, ax = plt.subplots(figsize=(8, 0.22 * len(est) + 1.2))
    y = np.arange(len(est))
    for i, e in enumerate(est):
        p = e.param
        if p.log:
            rel = lambda v: math.log10(max(v, 1e-300) / p.value0)
            lo, hi = rel(max(e.ci95[0], p.lo)), rel(min(e.ci95[1], p.hi))
            mid, blo, bhi = rel(e.value), rel(p.lo), rel(p.hi)
        else:
            half = max(p.hi - p.value0, p.value0 - p.lo)
            rel = lambda v: (v - p.value0) / half
            lo, hi = rel(max(e.ci95[0], p.lo)), rel(min(e.ci95[1], p.hi))
            mid, blo, bhi = rel(e.value), -1.0, 1.0
        ax.plot([blo, bhi], [i, i], color="0.85", lw=6)
        ax.plot([lo, hi], [i, i], color="tab:blue", lw=2)
        ax.plot([mid], [i], "o", color="red" if e.flags else "k", ms=4)
    ax.set_yticks(y)
    ax.set_yticklabels([e.param.name for e in est], fontsize=6)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("change: log10(v/v0) for scaled kinds, share of the range for additive kinds; "
                  "grey = bounds, blue = 95 % interval, red = flagged")
    ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def write_report(r: CalibrationResult, out: pathlib.Path, twin: str, recording: str,
                 notes: list[str], input_estimates: list[dict] | None = None,
                 runs: list[dict] | None = None, folds: FoldsCalibration | None = None) -> dict[str, pathlib.Path]:
    rep = report_dict(r, twin, recording, notes, input_estimates, runs, folds)
    paths = {"json": out / "report.json"}
    paths["json"].write_text(json.dumps(rep, indent=1, default=lambda o: float(o) if np.isscalar(o) else str(o)))
    paths["md"] = write_markdown(rep, out)
    paths["channels"] = out / "channels.png"
    plot_channels(r, paths["channels"])
    paths["parameters"] = out / "parameters.png"
    plot_parameters(r, paths["parameters"])
    return paths


def plot_input_estimate(est, time_s: np.ndarray, path: pathlib.Path, true_power: np.ndarray | None = None) -> None:
    """The estimated heat profile with its 95 % band (and the true heat when known)."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    e = est.block_edges_s / 3600.0
    fig, ax = plt.subplots(figsize=(10, 3.2))
    ax.fill_between(np.repeat(e, 2)[1:-1], np.repeat(est.power_ci95_w[:, 0], 2), np.repeat(est.power_ci95_w[:, 1], 2),
                    color="tab:blue", alpha=0.25, label="95 % band")
    ax.step(e[:-1], est.power_w, where="post", color="tab:blue", label="estimated heat")
    if true_power is not None:
        ax.plot(time_s / 3600.0, true_power, "k", lw=0.7, label="heat of the real input")
    ax.set_xlabel("time [h]")
    ax.set_ylabel(f"heat of the {est.input} sources [W]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
