"""Pictures of a demo run: the PNG of compensated versus uncompensated errors (like the
thesis's Figs 6.13-6.19) and the .rrd file of the whole bag for the rerun viewer."""
from __future__ import annotations

import pathlib
import sys
from typing import Any

import matplotlib
import numpy as np

from thermal_comp.demo.series import DemoSeries
from thermal_comp.demo.summary import compensation_in_effect
from thermal_comp.view.run import bag_to_rrd


def _no_good_spans_h(series: DemoSeries) -> list[tuple[float, float]]:
    spans = []
    for i, (t0, ph) in enumerate(series.phases):
        if ph == 2:
            t1 = series.phases[i + 1][0] if i + 1 < len(series.phases) else series.t_true[-1]
            spans.append((t0 / 3600.0, t1 / 3600.0))
    return spans


def plot(series: DemoSeries, summary: dict[str, Any], path: pathlib.Path) -> None:
    """One panel per error: uncompensated, compensated, prediction band, probing instants
    and no-good phases."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt   # after choosing the non-interactive backend
    comp = compensation_in_effect(series)
    n = len(series.components)
    fig, axes = plt.subplots(n, 1, figsize=(12, 2.1 * n + 0.6), sharex=True, squeeze=False)
    th = series.t_true / 3600.0
    ng_spans = _no_good_spans_h(series)
    for ax, c in zip(axes[:, 0], series.components):
        e = series.true[c]
        ax.plot(th, e, color="0.55", lw=1.0, label="uncompensated (twin truth)")
        ax.plot(th, e - comp[c], color="tab:blue", lw=1.0, label="compensated")
        if series.t_pred.size:
            tp = series.t_pred / 3600.0
            p, s = series.predicted[c], series.std[c]
            ax.plot(tp, p, color="tab:orange", lw=0.8, label="prediction")
            ok = np.isfinite(s)
            if ok.any():
                ax.fill_between(tp[ok], (p - 2 * s)[ok], (p + 2 * s)[ok], color="tab:orange", alpha=0.2,
                                lw=0, label="prediction ±2u")
        for t in series.probe_times_s:
            ax.axvline(t / 3600.0, color="tab:green", lw=0.4, alpha=0.5)
        for a, b in ng_spans:
            ax.axvspan(a, b, color="tab:red", alpha=0.12)
        es = summary["errors"].get(c, {})
        ax.set_ylabel(f"{c}\n[{series.units[c]}]")
        ax.set_title(f"{c}: P99 {es.get('p99_uncompensated', float('nan')):.1f} -> "
                     f"{es.get('p99_compensated', float('nan')):.1f} {series.units[c]}", fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=4)
    axes[-1, 0].set_xlabel("time [h]   (green: probing cycles, red: no-good phases)")
    fig.suptitle(f"{summary['machine']} / {summary['scenario']}: {summary['model_kind'].upper()} compensation, "
                 f"{summary['probing_cycles']} probing cycles, Q_prod {summary['q_prod_pct']} %")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_rrd(bag: pathlib.Path, rrd: pathlib.Path) -> int:
    """Log the whole bag into an .rrd file; the number of messages logged."""
    n, damage = bag_to_rrd(bag, rrd, app_id="thermal_comp_demo")   # with the bag view's blueprint
    if damage:
        print(f"warning: {damage}", file=sys.stderr)
    return n
