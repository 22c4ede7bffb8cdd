"""The outputs of ``thermal-comp evaluate``: a rich table, ``evaluation.json``, PNGs and a rerun .rrd.

The table has one row per baseline and model (open loop: MAE on test [validation] rows and the
ratio to the best baseline on those rows), and per adaptive model a row with its compensation
and, under it, holding that model's own probes (ratio = model / hold). A failed model is a row
with its reason. No rclpy here.
"""
from __future__ import annotations

import json
import math
import pathlib
import re
from typing import Any

import numpy as np
from rich.table import Table

from thermal_eval.evaluate.run import EvaluationResult
from thermal_eval.evaluate.spec import EvaluationData
from thermal_comp_common import plain_output


def _fig(c: dict, window: str, prefix: str = "") -> str:
    """MAE / RMSE / P99 of one window ("-" for a window without rows)."""
    v = [c.get(f"{prefix}{k}_{window}_um") for k in ("mae", "rmse", "p99")]
    return "-" if v[0] is None else " / ".join(f"{x:.3f}" if x is not None else "-" for x in v)


def _cell(c: dict, ratio_key: str, prefix: str = "") -> str:
    if "failed" in c:
        return "[red]failed[/red]"
    r = c.get(ratio_key)
    ratio = f" x{r:.2f}" if isinstance(r, (int, float)) and math.isfinite(r) else ""
    val = _fig(c, "validation", prefix)
    return f"{_fig(c, 'test', prefix)}{ratio}" + ("" if val == "-" else f"\n[{val}]")


def print_table(figures: dict[str, Any], console=None) -> None:
    console = console or plain_output.console(min_width=140)
    chs = figures["channels"]
    rows = figures["rows"]
    base = figures.get("ratio_baseline")
    table = Table(title=f"evaluate {figures['source']}: MAE / RMSE / P99 (um) on test rows {rows['test']} "
                        f"[validation rows {rows['validation']}]; x: MAE ratio to {base} (open loop) or to "
                        "holding the same probes (adaptive), same rows")
    table.add_column("mode")
    table.add_column("model")
    for ch in chs:
        table.add_column(ch, justify="right")
    table.add_column("probings (per h)", justify="right")
    failures = []
    for name, v in figures["open_loop"].items():
        table.add_row("open loop" if v["kind"] == "model" else "baseline", name,
                      *[_cell(v["channels"][ch], f"ratio_to_{base}_test") for ch in chs], "")
        failures += [f"{name} {ch}: {c['failed']}" for ch, c in v["channels"].items() if "failed" in c]
    for name, v in figures["adaptive"].items():
        if "failed" in v:
            table.add_row("adaptive", name, *["[red]failed[/red]"] * len(chs), "")
            failures.append(f"adaptive {name}: {v['failed']}")
            continue
        probes = f"{v['probings_after_calibration']} ({v['probings_per_h_after_calibration']:.2f})"
        if "load_probing" in v:         # the load-change rule the walk-forward chose: off, or delay/depth
            probes += f", after steps {v['probings_after_input_steps']} ({v['load_probing']['chosen']})"
        table.add_row("adaptive", name, *[_cell(v["channels"][ch], "ratio_to_hold_test") for ch in chs], probes)
        table.add_row("", f"  hold {name}'s probes",
                      *[("" if "failed" in v["channels"][ch] else _cell(v["channels"][ch], "", "hold_own_probes_"))
                        for ch in chs], "same")
        if "probe_phases" in v:
            _phase_rows(table, v, chs)
    console.print(table)
    console.print(f"open loop: x = MAE / {base}'s MAE on the same test rows (per channel); adaptive: x = MAE / "
                  "holding the same probes. Probings counted after the training (calibration) rows.")
    if figures.get("probe_phases", 1) > 1:
        console.print(f"phases: the probing clock delayed by i/{figures['probe_phases']} of the interval; mean: x = "
                      "mean MAE / holding's mean MAE; worst phase: largest MAE, x = largest ratio (test rows).")
    for line in quantised_notes(figures):
        console.print(line)
    for f in failures:
        console.print(f"[red]failed[/red] {f}")


def quantised_notes(figures: dict[str, Any]) -> list[str]:
    """One line per channel whose displacement is quantised (the step measured on the training
    rows) and whose dead band that step sets."""
    seen: dict[str, tuple[float, float]] = {}
    for row in figures["adaptive"].values():
        for ch, c in row.get("channels", {}).items():
            if c.get("quantised_step_um"):
                seen.setdefault(ch, (c["quantised_step_um"], c["dead_band_um"]))
    return [f"note: {ch} is quantised in steps of {q:g} um (measured on the training rows): changes below the "
            f"dead band of {b:g} um are not acted on" for ch, (q, b) in seen.items()]


def _phase_rows(table, v: dict, chs: list[str]) -> None:
    """Under an adaptive row scored at K probe phases: the phase mean (x its ratio to holding's
    phase mean), holding's phase mean, and the worst phase (x its largest ratio)."""
    ph = v["probe_phases"]
    counts = ph["probings_after_calibration"]
    label = f"{min(counts)}-{max(counts)}" if min(counts) != max(counts) else f"{counts[0]}"
    cells = {ch: v["channels"][ch].get("phases") for ch in chs}
    table.add_row("", f"  mean of {ph['k']} phases",
                  *["" if c is None else _cell(c["mean"], "ratio_to_hold_test") for c in cells.values()], label)
    table.add_row("", "  hold, mean of phases",
                  *["" if c is None else _cell(c["mean"], "", "hold_own_probes_") for c in cells.values()], "same")
    table.add_row("", "  worst phase",
                  *["" if c is None else _cell(c["worst"], "ratio_to_hold_test") for c in cells.values()], "")


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def write_json(figures: dict[str, Any], out: pathlib.Path) -> pathlib.Path:
    path = out / "evaluation.json"
    path.write_text(json.dumps(figures, indent=1, default=_json_default, allow_nan=True))
    return path


def _best(figures: dict, group: str) -> str | None:
    """The model with the lowest channel-mean test MAE in a group (for the plots)."""
    best = None
    for name, v in figures[group].items():
        if v.get("kind") != "model" or "failed" in v:
            continue
        cells = [c.get("mae_test_um") if c.get("mae_test_um") is not None else c.get("mae_validation_um")
                 for c in v["channels"].values()]
        if any(c is None for c in cells):
            continue
        score = float(np.mean(cells))
        if best is None or score < best[0]:
            best = (score, name)
    return None if best is None else best[1]


def plot(data: EvaluationData, result: EvaluationResult, out: pathlib.Path) -> pathlib.Path:
    """Measured vs compensation per channel after the training rows: the best open-loop model,
    the best adaptive model with its probe instants, and holding those probes."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    f = result.figures
    s = data.split
    rows = slice(s.n_train, s.n)
    th = data.time_s[rows] / 3600.0
    ol, ad = _best(f, "open_loop"), _best(f, "adaptive")
    chs = data.channels
    fig, axes = plt.subplots(len(chs), 1, figsize=(12, 2.8 * len(chs)), sharex=True, squeeze=False)
    for ax, ch in zip(axes[:, 0], chs):
        y = data.displacement_um[ch][rows]
        ax.plot(th, y, color="k", lw=1.5, label="measured")
        if ol and ch in result.open_loop.get(ol, {}):
            ax.plot(th, result.open_loop[ol][ch][rows], lw=1, label=f"open loop {ol}")
        if ad and ch in result.adaptive.get(ad, {}):
            ax.plot(th, result.adaptive[ad][ch][rows], lw=1, label=f"adaptive {ad}")
            ax.plot(th, result.hold[ad][ch][rows], lw=0.8, ls=":", label="hold its probes")
            pr = np.asarray(result.probe_rows[ad], dtype=int)
            lo = float(np.nanmin(y)) - 0.05 * (float(np.nanmax(y) - np.nanmin(y)) or 1.0)
            ax.plot(data.time_s[pr] / 3600.0, np.full(pr.size, lo), "|", color="C3", ms=8, label="probings")
        for sl in (w for _, w in s.windows()):
            ax.axvline(data.time_s[sl.start] / 3600.0, color="0.5", ls="--", lw=1)
        ax.set_ylabel(f"{ch} (um)")
    axes[0, 0].legend(loc="best", fontsize=7, ncol=3)
    axes[0, 0].set_title("after the training rows (dashed: start of the held-out windows); "
                         + ", ".join(f"{w} rows {sl.start}-{sl.stop - 1}" for w, sl in s.windows()), fontsize=9)
    axes[-1, 0].set_xlabel("time since start (h)")
    fig.tight_layout()
    path = out / "evaluation.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def entity_part(name: str) -> str:
    """A column name as one rerun entity-path part: characters other than letters, digits,
    '_', '-' and '.' become '_' (a name like 'delta L' would otherwise warn on every send)."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", name) or "_"


def write_rerun(data: EvaluationData, result: EvaluationResult, out: pathlib.Path) -> pathlib.Path:
    """Measured, every open-loop prediction, adaptive compensation and probe instants per channel."""
    import rerun as rr  # heavy: rerun only when writing a recording
    rec = rr.RecordingStream("thermal_comp_evaluate")
    path = out / "evaluation.rrd"
    rec.save(str(path))
    times = rr.TimeColumn("time", duration=np.asarray(data.time_s, dtype=float))

    def send(entity: str, values: np.ndarray) -> None:
        entity = "/".join(entity_part(x) for x in entity.split("/"))
        rr.send_columns(entity, indexes=[times], columns=rr.Scalars.columns(scalars=np.asarray(values, float)),
                        recording=rec)
    for ch in data.channels:
        send(f"{ch}/measured", data.displacement_um[ch])
        for name, per in result.open_loop.items():
            if ch in per:
                send(f"{ch}/open_loop/{name}", per[ch])
        for name, per in result.adaptive.items():
            if ch in per:
                send(f"{ch}/adaptive/{name}", per[ch])
    for name, pr in result.probe_rows.items():
        if pr:
            pt = rr.TimeColumn("time", duration=data.time_s[np.asarray(pr, dtype=int)])
            rr.send_columns(f"probings/{entity_part(name)}", indexes=[pt],
                            columns=rr.Scalars.columns(scalars=np.ones(len(pr))), recording=rec)
    rec.flush()
    rec.disconnect()
    return path
