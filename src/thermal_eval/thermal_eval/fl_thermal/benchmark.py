"""FL_THERMAL benchmark: our models on a real 46 h spindle recording.

``thermal-comp bench fl-thermal --json OUT [--out-dir DIR] [--quick] [--csv=PATH --rows=N --every=K --no-adaptive
--agp-load-probing --no-agp-calibrated]`` (suite options in the ``--name=value`` form).
The authors' chronological 60/20/20 split; open-loop models (lagged ridge, ARX simulation: the
generic ``evaluate`` models and baselines, run by :func:`thermal_eval.evaluate.run.evaluate`) and
adaptive models (``evaluate``'s adaptive rows at the benchmark's budget, the closed-loop rows fitted
on the training rows, the replayed TALC/AGP) scored by MAE on the test and validation rows, beside
the published numbers: FL_THERMAL is a dataset configuration of the generic path (its loader,
split, published numbers and budget live here and in ``fl_thermal_data``). Protocol, models and
figure keys: docs/fl_thermal.md.
"""
from __future__ import annotations

import argparse
import pathlib
import time
from typing import Any, Mapping, Sequence

import numpy as np
from rich.table import Table

from talc_model.open_loop.lagged_temperature_model import DEFAULT_ALPHA_GRID
from thermal_comp_common import plain_output
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_eval.evaluate.adaptive import ProbingBudget
from thermal_eval.evaluate.baselines import BASELINES
from thermal_eval.evaluate.run import evaluate
from thermal_eval.fl_thermal.adaptive import adaptive_configs, run_adaptive, select_talc_inputs
from thermal_eval.fl_thermal.data import (CHANNELS, FlThermalData, FlThermalError, Splits, as_evaluation_data,
                                          load_fl_thermal, mae)
from thermal_eval.evaluate.open_loop_models import GROUP_CANDIDATES as ARX_GROUP_CANDIDATES
from thermal_eval.evaluate.open_loop_models import arx_model, lagged_ridge_model

#: MAE (um) on the test rows, from the authors' README (shared/data/fl_thermal/README.md).
PUBLISHED_MAE_UM: dict[str, dict[str, float]] = {
    "RF": dict(zip(CHANNELS, (6.456, 4.501, 7.330, 7.178, 12.440))),
    "XGBoost": dict(zip(CHANNELS, (5.611, 4.966, 6.039, 7.804, 9.535))),
    "S2S1": dict(zip(CHANNELS, (5.576, 5.943, 4.183, 4.160, 6.499))),
    "S2S2": dict(zip(CHANNELS, (3.561, 3.755, 3.704, 3.461, 4.284))),
}
BEST_PUBLISHED = "S2S2"

# ----------------------------------------------------------------------------- open loop

#: benchmark name -> (generic model of :mod:`thermal_eval.evaluate.open_loop_models`, uses the spindle speed)
OPEN_LOOP_MODELS = {"lagged_ridge": ("lagged_ridge", False), "lagged_ridge_spindle": ("lagged_ridge_inputs", True)}
ARX_MODELS = {"arx_simulation": ("arx_simulation", False), "arx_simulation_spindle": ("arx_simulation_inputs", True)}


def _open_loop_cell(data: FlThermalData, splits: Splits, name: str, ch: str, cell: Mapping[str, Any],
                    pred: np.ndarray | None, with_spindle: bool) -> dict[str, Any]:
    """The benchmark's figure keys from one generic evaluate cell (a failure stays its reason)."""
    if "failed" in cell:
        return {"failed": cell["failed"]}
    p = dict(cell["params"])
    out: dict[str, Any] = {"mae_um": cell["mae_test_um"], "mae_validation_um": cell["mae_validation_um"]}
    if name in OPEN_LOOP_MODELS:
        y = data.displacement_um[ch]
        out.update(mae_train_um=round(mae(y[:splits.n_train], pred[:splits.n_train]), 3),
                   walk_forward_mae_um=p["walk_forward_mae_um"],
                   walk_forward_fold_mae_um=p["walk_forward_fold_mae_um"], taus_s=p["taus_s"], alpha=p["alpha"])
    elif name in ARX_MODELS:
        out.update(training_validation_rms_um=p["training_validation_rms_um"],
                   inputs=list(p["inputs"]) + (["spindle_krpm"] if with_spindle else []), na=p["na"], nb=p["nb"],
                   input_set_training_validation_rms_um=p["input_sets"])
    return out


def run_open_loop(data: FlThermalData, splits: Splits, *, tau_grid=None, alpha_grid=DEFAULT_ALPHA_GRID,
                  arx_groups: Sequence[int] = ARX_GROUP_CANDIDATES,
                  show_progress: bool = True) -> tuple[dict, dict[str, dict[str, np.ndarray]]]:
    """Figures and predictions of every open-loop model (lagged ridge with and without the
    spindle speed, ARX in simulation mode) and of the generic baselines, all through the generic
    ``evaluate`` path (:func:`thermal_eval.evaluate.run.evaluate`) on the authors' split."""
    ed = as_evaluation_data(data, splits)
    models = [lagged_ridge_model(name, spindle, tau_grid, alpha_grid) for name, (_, spindle) in OPEN_LOOP_MODELS.items()]
    models += [arx_model(name, spindle, False, arx_groups) for name, (_, spindle) in ARX_MODELS.items()]
    res = evaluate(ed, models=BASELINES + models, adaptive=False, show_progress=show_progress)
    figures: dict[str, Any] = {}
    predictions: dict[str, dict[str, np.ndarray]] = {}
    for name, (_, spindle) in {**OPEN_LOOP_MODELS, **ARX_MODELS}.items():
        per = res.figures["open_loop"][name]["channels"]
        predictions[name] = dict(res.open_loop[name])
        figures[name] = {ch: _open_loop_cell(data, splits, name, ch, per[ch], predictions[name].get(ch), spindle)
                         for ch in CHANNELS}
    baselines = {b.name: {ch: _open_loop_cell(data, splits, b.name, ch,
                                              res.figures["open_loop"][b.name]["channels"][ch], None, False) for ch in CHANNELS} for b in BASELINES}
    return figures, predictions, baselines


# ----------------------------------------------------------------------------- generic adaptive rows
#: the benchmark's budget: a probing every 2 h plus the model's own, at most one per hour after calibration
GENERIC_BUDGET = ProbingBudget(probe_every_h=2.0, max_probes_per_h=1.0, tolerance_um=1.0)
#: the closed-loop rows of ``evaluate`` fitted on the training rows (the authors' protocol
#: gives a model every training displacement); ``*_inputs*``: the spindle speed as an ARX input
CALIBRATED_ROWS = ("talc_calibrated", "talc_calibrated_inputs", "talc_calibrated_load_probing",
                   "talc_calibrated_inputs_load_probing")
AGP_CALIBRATED_ROW = "agp_calibrated"
#: row-level figures kept from an adaptive row of ``evaluate``
ROW_KEYS = ("probings_after_calibration", "probings_per_h_after_calibration", "q_prod_after_calibration_pct",
            "probings_asked_by_model", "q_prod_pct", "calibration", "calibration_probings", "calibration_end_h",
            "steps_probing_refused_by_budget", "no_good_phases", "load_change_phases", "recalibrations",
            "parameter_updates", "settings", "seconds")


def _adaptive_figures(row: Mapping[str, Any], contract: str) -> dict[str, Any]:
    """One adaptive row of ``evaluate`` in the benchmark's figure keys."""
    fig: dict[str, Any] = {"contract": contract}
    if "failed" in row:
        return {**fig, "failed": row["failed"], **{ch: {"failed": row["failed"]} for ch in CHANNELS}}
    for ch in CHANNELS:
        c = row["channels"][ch]
        fig[ch] = {"failed": c["failed"]} if "failed" in c else {
            "mae_um": c["mae_test_um"], "mae_validation_um": c["mae_validation_um"],
            "hold_last_measurement_mae_um": c["hold_own_probes_mae_test_um"],
            "hold_last_measurement_mae_validation_um": c["hold_own_probes_mae_validation_um"],
            **{k: c[k] for k in ("model_weight", "dead_band_um", "ratio_to_hold_test", "ratio_to_hold_validation")
               if k in c}}
    fig.update({k: row[k] for k in ROW_KEYS if k in row})
    fig["probing_cycles_test_rows"] = row["probings_test"]
    fig["probing_cycles_validation_rows"] = row["probings_validation"]
    return fig


def run_generic_adaptive(data: FlThermalData, splits: Splits, *, tau_grid=None, alpha_grid=DEFAULT_ALPHA_GRID,
                         arx_groups: Sequence[int] = ARX_GROUP_CANDIDATES, closed_loop: Sequence[str] = CALIBRATED_ROWS,
                         show_progress: bool = True
                         ) -> tuple[dict, dict[str, dict[str, np.ndarray]], dict[str, list[int]]]:
    """The adaptive rows of ``thermal-comp evaluate`` at the benchmark's budget on FL_THERMAL: the
    open-loop models ``arx_subgrid`` and ``lagged_ridge`` in its adaptive mode
    (:mod:`thermal_eval.evaluate.adaptive`) and the closed-loop rows ``closed_loop``
    (:mod:`thermal_eval.evaluate.model_rows`: TALC / AGP fitted on the training rows), in the
    benchmark's figure keys: MAE, holding the same probes, probings counted after calibration."""
    ed = as_evaluation_data(data, splits)
    models = [arx_model("arx_subgrid", False, True, arx_groups), lagged_ridge_model("lagged_ridge", False, tau_grid, alpha_grid)]
    res = evaluate(ed, models=models, adaptive=True, budget=GENERIC_BUDGET, show_progress=show_progress,
                   closed_loop=list(closed_loop))
    figures = {m.name: _adaptive_figures(res.figures["adaptive"][m.name], "generic adaptive (thermal-comp evaluate)")
               for m in models}
    figures.update({name: _adaptive_figures(res.figures["adaptive"][name], "closed-loop row (thermal-comp evaluate "
                                            "--closed-loop), calibrated on the training rows") for name in closed_loop})
    return figures, {k: v for k, v in res.adaptive.items()}, {k: v for k, v in res.probe_rows.items()}


# ----------------------------------------------------------------------------- report

def print_table(figures: Mapping[str, Any]) -> None:
    """Our MAE beside the published numbers (test rows), and our validation-row MAE."""
    table = Table(title="FL_THERMAL: MAE (um) per channel, test rows 6669-8891 [validation rows 8892-11114]")
    table.add_column("model")
    for ch in CHANNELS:
        table.add_column(ch, justify="right")
    table.add_column("Q_prod %", justify="right")
    for name, per in PUBLISHED_MAE_UM.items():
        table.add_row(f"published {name}", *[f"{per[ch]:.3f}" for ch in CHANNELS], "")
    best = PUBLISHED_MAE_UM[BEST_PUBLISHED]
    for group in ("baselines", "open_loop", "adaptive"):
        for name, per in figures.get(group, {}).items():
            cells = []
            for ch in CHANNELS:
                if "mae_um" not in per[ch]:
                    cells.append("[red]failed[/red]")
                    continue
                v, vv = per[ch]["mae_um"], per[ch]["mae_validation_um"]
                target = best[ch] if group != "adaptive" else 1.0
                style = "green" if v <= target else "red"
                cells.append(f"[{style}]{v:.3f}[/{style}] [{vv:.3f}]")
            q = f"{per['q_prod_pct']:.2f}" if "q_prod_pct" in per else ""
            if "q_prod_after_calibration_pct" in per:
                q += f" ({per['q_prod_after_calibration_pct']:.2f})"
            table.add_row(f"{group} {name}", *cells, q)
            if all("hold_last_measurement_mae_um" in per[ch] for ch in CHANNELS):
                # what holding each of this model's measurements would give on its own schedule
                table.add_row(f"  (hold {name}'s probes)",
                              *[f"{per[ch]['hold_last_measurement_mae_um']:.3f} "
                                f"[{per[ch]['hold_last_measurement_mae_validation_um']:.3f}]" for ch in CHANNELS],
                              "same")
    console = plain_output.console(min_width=140)
    console.print(table)
    console.print(f"green: beats {BEST_PUBLISHED} (open loop) / <= 1 um (adaptive) on the test rows. "
                  "Q_prod (in brackets: after calibration) charges 95 s per probing; the rows calibrated "
                  "on the training rows are charged one probing per 5-min grid sample of them. "
                  "'hold ...'s probes': each measurement of that model held until its next one (the baseline "
                  "its probing schedule alone gives).")


def plot_predictions(data: FlThermalData, splits: Splits, predictions: Mapping[str, Mapping[str, np.ndarray]],
                     path: str | pathlib.Path) -> None:
    """PNG: measured vs predicted per channel on the test and validation rows (Agg backend)."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    fig, axes = plt.subplots(len(CHANNELS), 1, figsize=(12, 3.0 * len(CHANNELS)), sharex=True)
    rows = slice(splits.n_train, splits.n)
    th = data.time_s[rows] / 3600.0
    for ax, ch in zip(axes, CHANNELS):
        ax.plot(th, data.displacement_um[ch][rows], color="k", lw=1.5, label="measured")
        for label, per in predictions.items():
            ax.plot(th, per[ch][rows], lw=1, label=label)
        ax.axvline(data.time_s[splits.test_end] / 3600.0, color="0.5", ls="--", lw=1)
        ax.set_ylabel(f"{ch} (um)")
        ax.set_title(f"{ch}: test rows (left of the dashed line), validation rows (right)", fontsize=9)
    axes[0].legend(loc="best", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time since start (h)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


#: adaptive models drawn in the prediction plot / in the adaptive plot (with their probe instants)
ADAPTIVE_IN_PREDICTION_PLOT = ("talc_calibrated", "agp")
ADAPTIVE_PLOT = ("talc_calibrated", "talc_calibrated_load_probing", "agp", "agp_calibrated", "agp_load_probing",
                 "arx_subgrid")   # those that were run


def plot_adaptive(data: FlThermalData, splits: Splits, compensation: Mapping[str, Mapping[str, np.ndarray]],
                  probe_rows: Mapping[str, Sequence[int]], path: str | pathlib.Path) -> None:
    """PNG: measured vs compensation per channel on the test and validation rows, each model's
    probe instants as ticks under the curves (Agg backend)."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    fig, axes = plt.subplots(len(CHANNELS), 1, figsize=(12, 3.0 * len(CHANNELS)), sharex=True)
    rows = slice(splits.n_train, splits.n)
    th = data.time_s[rows] / 3600.0
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, ch in zip(axes, CHANNELS):
        y = data.displacement_um[ch][rows]
        ax.plot(th, y, color="k", lw=1.5, label="measured")
        lo, span = float(np.min(y)), float(np.ptp(y)) or 1.0
        for i, (label, per) in enumerate(compensation.items()):
            c = colors[i % len(colors)]
            ax.plot(th, per[ch][rows], lw=1, color=c, label=f"{label} (MAE test {_mae_rows(data, splits, per, ch)})")
            pr = [r for r in probe_rows.get(label, []) if splits.n_train <= r < splits.n]
            ax.plot(data.time_s[pr] / 3600.0, np.full(len(pr), lo - (0.06 + 0.05 * i) * span), "|", color=c, ms=8)
        ax.axvline(data.time_s[splits.test_end] / 3600.0, color="0.5", ls="--", lw=1)
        ax.set_ylabel(f"{ch} (um)")
        ax.legend(loc="best", fontsize=7)
    axes[0].set_title("adaptive: measured vs compensation; ticks = probings (test rows | validation rows)", fontsize=9)
    axes[-1].set_xlabel("time since start (h)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _mae_rows(data: FlThermalData, splits: Splits, per: Mapping[str, np.ndarray], ch: str) -> str:
    return f"{mae(data.displacement_um[ch][splits.test], per[ch][splits.test]):.2f} um"


def run_benchmark(data: FlThermalData, *, out_dir: str | pathlib.Path | None = None, adaptive: bool = True,
                  tau_grid=None, alpha_grid=DEFAULT_ALPHA_GRID, adaptive_overrides: Mapping[str, dict] | None = None,
                  talc_groups: Sequence[int] | None = None, arx_groups: Sequence[int] | None = None,
                  agp_load_probing: bool = False, agp_calibrated: bool = True,
                  show_progress: bool = True) -> dict[str, Any]:
    """The whole protocol on ``data``; returns the figures (and writes the PNG into ``out_dir``)."""
    splits = Splits.authors(len(data))
    t0 = time.perf_counter()
    figures: dict[str, Any] = {
        "rows": {"train": [0, splits.n_train - 1], "test": [splits.n_train, splits.test_end - 1],
                 "validation": [splits.test_end, splits.n - 1]},
        "published": {name: dict(per) for name, per in PUBLISHED_MAE_UM.items()},
    }
    with single_thread_blas(openmp=True):   # small dense problems: BLAS threads only contend on a shared machine
        figures["open_loop"], predictions, figures["baselines"] = run_open_loop(
            data, splits, tau_grid=tau_grid, alpha_grid=alpha_grid, arx_groups=arx_groups or ARX_GROUP_CANDIDATES,
            show_progress=show_progress)
    figures["open_loop_s"] = round(time.perf_counter() - t0, 1)
    if adaptive:
        overrides = dict(adaptive_overrides or {})
        unknown = sorted(set(overrides) - {"talc_own_cp", "agp", "agp_load_probing"})
        if unknown:
            raise FlThermalError(f"adaptive_overrides: {unknown} are not replayed adaptive models "
                                 "(talc_own_cp, agp, agp_load_probing)")
        t1 = time.perf_counter()
        closed_loop = CALIBRATED_ROWS + ((AGP_CALIBRATED_ROW,) if agp_calibrated else ())
        figures["adaptive"], adaptive_pred, probe_rows = run_generic_adaptive(
            data, splits, tau_grid=tau_grid, alpha_grid=alpha_grid, arx_groups=arx_groups or ARX_GROUP_CANDIDATES,
            closed_loop=closed_loop, show_progress=show_progress)
        groups = {} if talc_groups is None else {"candidates": talc_groups}
        talc_inputs, talc_scores = select_talc_inputs(data, splits, overrides=overrides.get("talc_own_cp"),
                                                      show_progress=show_progress, **groups)
        configs = adaptive_configs(data, splits, talc_inputs, agp_load_probing=agp_load_probing)
        for name, extra in overrides.items():
            if name not in configs:
                raise FlThermalError(f"adaptive_overrides: {name!r} is not run (agp_load_probing needs "
                                     "agp_load_probing=True)")
            configs[name][1].update(extra)
        replay_fig, replay_pred, replay_probes = run_adaptive(data, splits, configs, show_progress=show_progress)
        replay_fig["talc_own_cp"]["inputs"] = list(talc_inputs)
        replay_fig["talc_own_cp"]["input_selection_training_mae_um"] = talc_scores
        figures["adaptive"].update(replay_fig)
        adaptive_pred.update(replay_pred)
        probe_rows.update(replay_probes)
        figures["adaptive_s"] = round(time.perf_counter() - t1, 1)
        predictions.update({f"adaptive {k}": adaptive_pred[k] for k in ADAPTIVE_IN_PREDICTION_PLOT})
    best = PUBLISHED_MAE_UM[BEST_PUBLISHED]
    figures["open_loop_beats_s2s2"] = {name: {ch: bool(per[ch].get("mae_um", np.inf) < best[ch])
                                              for ch in CHANNELS} for name, per in figures["open_loop"].items()}
    if out_dir is not None:
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        png = out / "fl_thermal_predictions.png"
        plot_predictions(data, splits, predictions, png)
        figures["plot"] = str(png)
        if adaptive:
            png = out / "fl_thermal_adaptive.png"
            plot_adaptive(data, splits, {k: adaptive_pred[k] for k in ADAPTIVE_PLOT if k in adaptive_pred},
                          probe_rows, png)
            figures["plot_adaptive"] = str(png)
    return figures


def _parse_extra(extra: Sequence[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="thermal-comp bench fl-thermal", description=__doc__.split("\n\n")[0])
    ap.add_argument("--csv", default=None, help="FL_THERMAL CSV (default: $THERMAL_COMP_SHARED/data/fl_thermal/fl_thermal.csv)")
    ap.add_argument("--rows", type=int, default=None, help="use only the first N rows (smoke runs)")
    ap.add_argument("--every", type=int, default=1, help="use every K-th row")
    ap.add_argument("--no-adaptive", action="store_true", help="open loop only")
    ap.add_argument("--no-agp-calibrated", action="store_true",
                    help="skip the AGP calibrated on the training rows (its walk-forward takes a few minutes)")
    ap.add_argument("--agp-load-probing", action="store_true",
                    help="also replay the AGP with dense probing after every spindle-speed change (slow)")
    return ap.parse_args([e for e in extra if e != "--"])


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Bench entry point (``thermal_eval.bench.cli``: fl-thermal). ``--quick``: every 4th row (60 s)."""
    opts = _parse_extra(getattr(args, "extra", None) or [])
    every = opts.every if opts.every != 1 or not getattr(args, "quick", False) else 4
    data = load_fl_thermal(opts.csv, rows=opts.rows, every=every)
    figures = run_benchmark(data, out_dir=getattr(args, "out_dir", None), adaptive=not opts.no_adaptive,
                            agp_load_probing=opts.agp_load_probing, agp_calibrated=not opts.no_agp_calibrated)
    figures["every_nth_row"] = every
    print_table(figures)
    return figures
