"""Parameter sweep of TALC over the Blaser thesis's Table 6.1 grid (§6.3), pure core (no rclpy).

Table 6.1 varies five parameters (the CP interval 5 min, the ACLs 5 um / 15 um/m, n_a max 1
and n_b max 10 are fixed):

=================================  ==============================================
calibration phase length (h)       8.5 12 16 24 36 48 60
measurement interval post-CP (h)   1 2 3 4 5 6 7 8 9 10 11 12 24 inf
measurement interval in NG (min)   5 10 15 20 25 30 inf
measurements per NG phase          6 12 18 24 inf
parameter update interval (h)      8 16 24 ... 96 inf
=================================  ==============================================

The full factorial is 7 x 14 x 7 x 5 x 13 = 44,590; the thesis ran "all logical
combinations", 2,191 per load case, without saying which those are (spec §4.7 [GAP]).
Our reconstruction, which gives exactly 2,191 = 7 x (13 x 6 x 4 + 1):

- post-CP interval = inf: no probing after the CP, so no no-good phase and no new data for an
  update can ever occur; the NG and update parameters are meaningless -> one combination per
  CP length;
- NG interval = inf (a no-good phase that never measures) and NG measurements = inf (a
  no-good phase that never ends) are not logical settings of a no-good phase -> left out;
- the parameter update interval is not listed in Tables 6.2 and 6.3 (spec §4.7), i.e. it was
  not one of the varied dimensions of these combinations: it is held at one value per sweep
  (``update_interval_h``, default 24 h as Table 6.4) and can be swept separately through
  ``--grid-subset update_interval_h=...`` (which then multiplies the grid).

Results go to a JSONL file, one line per finished combination, flushed as it is written, so an
interrupted sweep loses nothing and a rerun only computes the missing lines. Every line
carries a fingerprint of the run (recording, model kind, base configuration, probe noise),
and a results file of another run is refused.

The best set is the thesis's balanced criterion (6.2) turned around: the
lowest P99_lin among the combinations with Q_prod >= 95 % (ties: the higher Q_prod).
Every line also carries probe-and-hold at that combination's Q_prod (the baseline to beat: no model,
even probes, same noise, same instants; ``thermal_comp_common.probe_and_hold``).
"""
from __future__ import annotations

import csv
import hashlib
import itertools
import json
import math
import pathlib
import statistics
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from thermal_comp_common.metrics import Q_PROD_MIN_PCT
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_eval.replay.baseline_beside import beside_probe_and_hold
from thermal_eval.replay.summary import build_model, probe_noise, summarise
from thermal_eval.replay.virtual_experiment import run_virtual_experiment

INF = math.inf
#: Table 6.1 ranges of the five varied parameters (TalcConfig field names).
CP_LENGTH_H = (8.5, 12.0, 16.0, 24.0, 36.0, 48.0, 60.0)
POST_CP_INTERVAL_H = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 24.0, INF)
NG_INTERVAL_MIN = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, INF)
NG_MEASUREMENTS = (6.0, 12.0, 18.0, 24.0, INF)
UPDATE_INTERVAL_H = (8.0, 16.0, 24.0, 32.0, 40.0, 48.0, 56.0, 64.0, 72.0, 80.0, 88.0, 96.0, INF)
TABLE_6_1 = {"cp_length_h": CP_LENGTH_H, "post_cp_interval_h": POST_CP_INTERVAL_H,
             "ng_interval_min": NG_INTERVAL_MIN, "ng_measurements": NG_MEASUREMENTS,
             "update_interval_h": UPDATE_INTERVAL_H}
#: Combinations per load case reported by the thesis (§6.3, "all logical combinations").
THESIS_COMBINATIONS_PER_LOAD_CASE = 2191
#: The thesis's three inputs for load cases A-C (D: WS replaced by the MWF sensor, which the
#: twin records in the same ``ws_mwf`` column).
THESIS_TALC_INPUTS = ("ambient", "ws_mwf", "c_coolant_delta")
#: The sweep's default inputs: the thesis's three plus the MWF state the CNC knows (M08/M09,
#: MachineState ``coolant_on``). The thesis names NC signals such as the MWF state as possible
#: inputs that its experiments did not use (spec §3); switching MWF switches a convective heat
#: flow (jets on the table and the B body) that one temperature at a tube outlet shows only
#: as a lagged, partial echo. A dry cell's flag never varies and TALC leaves it out
#: (``TalcConfig.min_input_range``), so load cases A-C are unchanged by it.
TALC_INPUTS = THESIS_TALC_INPUTS + ("coolant_on",)


class SweepError(ValueError):
    """Bad sweep input; the message names the key / file / line and value."""


@dataclass(frozen=True)
class SweepPoint:
    """One combination of the five Table 6.1 parameters."""

    cp_length_h: float
    post_cp_interval_h: float
    ng_interval_min: float
    ng_measurements: float
    update_interval_h: float

    def key(self) -> str:
        """Stable identifier of the combination (the resume key of the results file)."""
        return ",".join(f"{k}={_fmt(v)}" for k, v in asdict(self).items())

    def config(self) -> dict[str, float]:
        return asdict(self)


def _fmt(v: float) -> str:
    return "inf" if math.isinf(v) else f"{v:g}"


def table_6_1_grid(update_interval_h: float = 24.0) -> list[SweepPoint]:
    """The 2,191 logical combinations of Table 6.1 (see the module docstring for the rules)."""
    points = []
    for cp in CP_LENGTH_H:
        for post in POST_CP_INTERVAL_H:
            if math.isinf(post):
                # no probing after the CP: NG and update settings never act; the values stored
                # are the defaults of Table 6.4 so the configuration stays valid
                points.append(SweepPoint(cp, post, 10.0, 12.0, update_interval_h))
                continue
            for ngi, ngm in itertools.product(NG_INTERVAL_MIN, NG_MEASUREMENTS):
                if math.isinf(ngi) or math.isinf(ngm):
                    continue
                points.append(SweepPoint(cp, post, ngi, ngm, update_interval_h))
    return points


def parse_grid_subset(text: str) -> dict[str, tuple[float, ...]]:
    """``"cp_length_h=8.5,12;post_cp_interval_h=2,inf"`` -> allowed values per parameter."""
    out: dict[str, tuple[float, ...]] = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        key, sep, values = part.partition("=")
        key = key.strip()
        if not sep or key not in TABLE_6_1:
            raise SweepError(f"--grid-subset {part!r}: expected PARAM=v1,v2 with PARAM one of {list(TABLE_6_1)}")
        vals = []
        for raw in values.split(","):
            raw = raw.strip()
            try:
                v = float(raw)
            except ValueError:
                raise SweepError(f"--grid-subset {key}: {raw!r} is not a number (or inf)") from None
            if math.isnan(v) or v <= 0:
                raise SweepError(f"--grid-subset {key}: {raw!r} must be > 0 (or inf)")
            vals.append(v)
        if not vals:
            raise SweepError(f"--grid-subset {key}: no values")
        out[key] = tuple(vals)
    return out


def select_points(grid: Sequence[SweepPoint], subset: Mapping[str, Sequence[float]] | None = None,
                  limit: int | None = None) -> list[SweepPoint]:
    """Points of ``grid`` whose parameters are in ``subset``; ``update_interval_h`` in the subset
    replaces the grid's single value (each point once per listed value). ``limit`` keeps that
    many points spread evenly over the (ordered) selection."""
    subset = dict(subset or {})
    updates = subset.pop("update_interval_h", None)
    pts = [p for p in grid if all(getattr(p, k) in vs for k, vs in subset.items())]
    if updates is not None:
        pts = [SweepPoint(p.cp_length_h, p.post_cp_interval_h, p.ng_interval_min, p.ng_measurements, u)
               for p in pts for u in updates]
    if limit is not None:
        if limit < 1:
            raise SweepError(f"--limit: {limit} must be >= 1")
        if limit < len(pts):
            idx = np.unique(np.round(np.linspace(0, len(pts) - 1, limit)).astype(int))
            pts = [pts[i] for i in idx]
    return pts


# ------------------------------------------------------------------ one combination
@dataclass
class SweepRun:
    """What every combination of one sweep shares."""

    model_kind: str
    base_config: dict
    probe_noise_linear_um: float
    probe_noise_angular_um_per_m: float
    probe_resolution_um: float
    seed: int
    recording_label: str

    def fingerprint(self) -> str:
        blob = json.dumps({**asdict(self)}, sort_keys=True, default=str)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def evaluate_point(recording, run: SweepRun, point: SweepPoint) -> dict[str, Any]:
    """Replay ``recording`` through a model configured with ``run.base_config`` + ``point``."""
    config = dict(run.base_config)
    config.update(point.config())
    t0 = time.perf_counter()
    model = build_model(run.model_kind, config)
    res = run_virtual_experiment(recording, model,
                                 probe_noise_um=probe_noise(model.component_names, run.probe_noise_linear_um,
                                                            run.probe_noise_angular_um_per_m),
                                 probe_resolution_um=run.probe_resolution_um, seed=run.seed,
                                 compute_metrics=False)
    summary = summarise(res, model.status(float(res.time_s[-1])))
    return {"key": point.key(), "run": run.fingerprint(), "params": point.config(),
            "p99_lin_um": summary["p99_lin_um"], "p99_ang_um_per_m": summary["p99_ang_um_per_m"],
            "q_prod_pct": summary["q_prod_pct"],
            "probe_and_hold": probe_and_hold_row(res, summary["q_prod_pct"], run),
            "probing_cycles": summary["probing_cycles"],
            "no_good_phases": summary["no_good_phases"], "parameter_updates": summary["parameter_updates"],
            "calibration_h": summary["calibration_h"],
            "p99": {c: v["p99"] for c, v in summary["components"].items()},
            "rms": {c: v["rms"] for c, v in summary["components"].items()},
            "seconds": time.perf_counter() - t0}


def probe_and_hold_row(res, q_prod_pct: float, run: SweepRun) -> dict[str, float]:
    """Probe-and-hold at the combination's Q_prod over the same instants as its P99 (the
    compensation part, as ``summarise``) and over the whole run, beside the model's figures.
    NaN where the Q_prod leaves no even probing interval (0 or no finite value)."""
    nan = math.nan
    out = {"p99_lin_um": nan, "p99_ang_um_per_m": nan, "interval_h": nan, "p99_lin_ratio": nan,
           "whole_run_p99_lin_um": nan, "whole_run_model_p99_lin_um": nan, "whole_run_p99_lin_ratio": nan}
    if not (math.isfinite(q_prod_pct) and 0.0 < q_prod_pct < 100.0):
        return out
    noise = probe_noise(res.components, run.probe_noise_linear_um, run.probe_noise_angular_um_per_m)
    figs, _ = beside_probe_and_hold(res, q_prod_pct, noise, run.probe_resolution_um, seed=run.seed)
    comp, whole = figs.get("compensation_part"), figs.get("whole_run")
    if comp is not None:
        base = comp["probe_and_hold"]
        out.update(p99_lin_um=base["p99_lin_um"], p99_ang_um_per_m=base["p99_ang_um_per_m"],
                   interval_h=base["interval_h"], p99_lin_ratio=comp["p99_lin_ratio"])
    if whole is not None:
        out.update(whole_run_p99_lin_um=whole["probe_and_hold"]["p99_lin_um"],
                   whole_run_model_p99_lin_um=whole["model"]["p99_lin_um"],
                   whole_run_p99_lin_ratio=whole["p99_lin_ratio"])
    return out


def _sweep_task(shared, point: SweepPoint) -> dict[str, Any]:
    """One combination on a worker of the task engine; ``shared`` = (recording, run, evaluate)."""
    recording, run, evaluate = shared
    return evaluate(recording, run, point)


# ------------------------------------------------------------------ results file
def _encode(value):
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, dict):
        return {k: _encode(v) for k, v in value.items()}
    return value


def _decode(value):
    if isinstance(value, str) and value in ("nan", "inf", "-inf"):
        return float(value)
    if isinstance(value, dict):
        return {k: _decode(v) for k, v in value.items()}
    return value


def read_results(path: str | pathlib.Path, fingerprint: str | None = None) -> tuple[list[dict], list[str]]:
    """Finished lines of a results file and warnings. A line cut off by an interruption (the
    last one, not valid JSON) is skipped with a warning and will be recomputed; a line of
    another run (fingerprint) is an error naming the line."""
    path = pathlib.Path(path)
    if not path.exists():
        return [], []
    rows, warnings = [], []
    lines = path.read_text().splitlines()
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = _decode(json.loads(line))
        except json.JSONDecodeError:
            warnings.append(f"{path}:{i}: incomplete line skipped (interrupted write); it is recomputed")
            continue
        if not isinstance(row, dict) or "key" not in row:
            raise SweepError(f"{path}:{i}: not a sweep result line (no 'key')")
        if fingerprint is not None and row.get("run") != fingerprint:
            raise SweepError(f"{path}:{i}: result of another run (run {row.get('run')!r}, this run "
                             f"{fingerprint!r}: other recording, model or base configuration); "
                             f"use another results file")
        rows.append(row)
    return rows, warnings


def _append(fh, row: Mapping[str, Any]) -> None:
    fh.write(json.dumps(_encode(dict(row)), sort_keys=True) + "\n")
    fh.flush()


def _repair_tail(path: pathlib.Path) -> None:
    """Drop an unterminated last line so new lines start on a fresh one."""
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        path.write_bytes(data[: data.rfind(b"\n") + 1])


def run_sweep(recording, run: SweepRun, points: Sequence[SweepPoint], results_path: str | pathlib.Path,
              jobs: int = 1, progress: bool = True,
              evaluate: Callable[[Any, SweepRun, SweepPoint], dict] | None = None,
              engine: EngineSpec | None = None) -> dict[str, Any]:
    """Evaluate every point not yet in ``results_path`` (JSONL, appended as each finishes).

    ``engine`` says where the replays run (:mod:`thermal_comp_common.runtime.task_engine`: the local
    process pool, or a Dask cluster); without it, a local pool of ``jobs`` processes.
    ``evaluate`` replaces :func:`evaluate_point` (a module-level function, so it reaches the
    workers). Returns ``{"rows": all rows of the selected points, "computed": n,
    "skipped": n, "warnings": [...]}``.
    """
    if jobs < 1:
        raise SweepError(f"--jobs: {jobs} must be >= 1")
    engine = engine or EngineSpec("local", workers=jobs)
    results_path = pathlib.Path(results_path)
    results_path.parent.mkdir(parents=True, exist_ok=True)
    fp = run.fingerprint()
    done_rows, warnings = read_results(results_path, fp)
    done = {r["key"]: r for r in done_rows}
    todo = [p for p in points if p.key() not in done]
    _repair_tail(results_path)
    new: dict[str, dict] = {}
    bar = None
    if progress:
        bar = tqdm(total=len(todo), desc="sweep", unit="comb")
    try:
        with results_path.open("a") as fh:
            shared = (recording, run, evaluate or evaluate_point)
            for _, row in map_tasks(_sweep_task, shared, todo, engine):
                _append(fh, row)               # written the moment it arrives: an interruption loses nothing
                new[row["key"]] = row
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    rows = [done.get(p.key()) or new[p.key()] for p in points]
    return {"rows": rows, "computed": len(new), "skipped": len(points) - len(todo), "warnings": warnings}


# ------------------------------------------------------------------ analysis
def best_under_constraint(rows: Iterable[Mapping[str, Any]], q_prod_min_pct: float = Q_PROD_MIN_PCT):
    """The row with the lowest P99_lin among those with Q_prod >= ``q_prod_min_pct`` (ties: the
    higher Q_prod), or None if no row meets the constraint."""
    ok = [r for r in rows if math.isfinite(r["p99_lin_um"]) and math.isfinite(r["q_prod_pct"])
          and r["q_prod_pct"] >= q_prod_min_pct]
    if not ok:
        return None
    return min(ok, key=lambda r: (r["p99_lin_um"], -r["q_prod_pct"]))


def max_q_prod_front(rows: Iterable[Mapping[str, Any]], limits_um: Sequence[float]) -> list[float]:
    """Criterion (6.2) per limit X: the highest Q_prod with P99_lin < X (NaN if none), Fig. 6.10."""
    rows = [r for r in rows if math.isfinite(r["p99_lin_um"]) and math.isfinite(r["q_prod_pct"])]
    out = []
    for x in limits_um:
        q = [r["q_prod_pct"] for r in rows if r["p99_lin_um"] < x]
        out.append(max(q) if q else math.nan)
    return out


TABLE_COLUMNS = ("cp_length_h", "post_cp_interval_h", "ng_interval_min", "ng_measurements", "update_interval_h",
                 "p99_lin_um", "p99_ang_um_per_m", "q_prod_pct", "probing_cycles", "no_good_phases",
                 "parameter_updates", "seconds")
#: Probe-and-hold at each row's Q_prod (``probe_and_hold_row``), written beside the model's columns.
PROBE_AND_HOLD_COLUMNS = ("p99_lin_um", "p99_ang_um_per_m", "p99_lin_ratio", "whole_run_model_p99_lin_um",
                          "whole_run_p99_lin_um", "whole_run_p99_lin_ratio")


def format_probe_and_hold(row: Mapping[str, Any]) -> str:
    """One line: the row's P99_lin beside probe-and-hold at its Q_prod (compensation part and
    whole run), or a note when the row has none (a results file written before the baseline)."""
    b = row.get("probe_and_hold")
    if not b or not math.isfinite(b.get("p99_lin_um", math.nan)):
        return "probe-and-hold: n/a (no finite Q_prod, or a results line written without the baseline)"
    return (f"probe-and-hold at the same Q_prod {row['q_prod_pct']:.2f} % (a probe every {b['interval_h']:.2f} h): "
            f"P99_lin {b['p99_lin_um']:.2f} um over the compensation part (model / probe-and-hold = "
            f"{b['p99_lin_ratio']:.2f}), whole run model {b['whole_run_model_p99_lin_um']:.2f} vs "
            f"{b['whole_run_p99_lin_um']:.2f} um ({b['whole_run_p99_lin_ratio']:.2f}; goal: at most 0.5)")


def write_table(rows: Sequence[Mapping[str, Any]], path: str | pathlib.Path) -> None:
    """CSV of all rows sorted by P99_lin (the sweep's results table)."""
    rows = sorted(rows, key=lambda r: (r["p99_lin_um"] if math.isfinite(r["p99_lin_um"]) else math.inf,
                                       -r["q_prod_pct"]))
    comps = list(rows[0]["p99"]) if rows else []
    with pathlib.Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(TABLE_COLUMNS) + [f"p99_{c}" for c in comps]
                   + [f"probe_and_hold_{k}" for k in PROBE_AND_HOLD_COLUMNS])
        for r in rows:
            vals = [r["params"][k] for k in TABLE_COLUMNS[:5]] + [r[k] for k in TABLE_COLUMNS[5:]]
            base = r.get("probe_and_hold") or {}
            w.writerow([_fmt(v) if isinstance(v, float) else v for v in vals] +
                       [_fmt(r["p99"].get(c, math.nan)) for c in comps] +
                       [_fmt(float(base.get(k, math.nan))) for k in PROBE_AND_HOLD_COLUMNS])


def seconds_per_combination(rows: Iterable[Mapping[str, Any]]) -> float:
    """Median replay wall time of the rows (s)."""
    s = [float(r["seconds"]) for r in rows if "seconds" in r]
    return statistics.median(s) if s else math.nan


def plot_sweep(rows: Sequence[Mapping[str, Any]], out_dir: str | pathlib.Path, title: str = "",
               q_prod_min_pct: float = Q_PROD_MIN_PCT) -> list[pathlib.Path]:
    """PNGs like the thesis's Fig. 6.9 (P99_lin and P99_ang versus Q_prod per combination) and
    Fig. 6.10 (highest Q_prod reached with P99_lin < X, versus X)."""
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    q = np.array([r["q_prod_pct"] for r in rows], float)
    lin = np.array([r["p99_lin_um"] for r in rows], float)
    ang = np.array([r["p99_ang_um_per_m"] for r in rows], float)
    best = best_under_constraint(rows, q_prod_min_pct)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharex=True)
    for ax, y, name, unit in ((axes[0], lin, "P99_lin", "um"), (axes[1], ang, "P99_ang", "um/m")):
        ax.scatter(q, y, s=10, alpha=0.6)
        ax.axvline(q_prod_min_pct, color="0.5", ls="--", lw=1, label=f"Q_prod = {q_prod_min_pct:g} %")
        ax.set_xlabel("Q_prod (%)")
        ax.set_ylabel(f"{name} ({unit})")
        ax.set_title(f"{title} {name} vs Q_prod ({len(rows)} combinations)".strip())
        ax.grid(True, alpha=0.3)
    if best is not None:
        axes[0].scatter([best["q_prod_pct"]], [best["p99_lin_um"]], color="r", s=40, zorder=3,
                        label=f"best: {best['p99_lin_um']:.2f} um at {best['q_prod_pct']:.2f} %")
    axes[0].legend(loc="best", fontsize=8)
    fig.tight_layout()
    p1 = out_dir / "p99_vs_qprod.png"
    fig.savefig(p1, dpi=100)
    plt.close(fig)
    finite = lin[np.isfinite(lin)]
    hi = max(10.0, float(np.ceil(finite.max()))) if finite.size else 10.0
    limits = np.linspace(1.0, hi, 200)
    front = max_q_prod_front(rows, limits)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot(limits, front, drawstyle="steps-post")
    ax.set_xlabel("P99_lin limit X (um)")
    ax.set_ylabel("highest Q_prod with P99_lin < X (%)")
    ax.set_title(f"{title} criterion (6.2)".strip())
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    p2 = out_dir / "qprod_vs_p99_limit.png"
    fig.savefig(p2, dpi=100)
    plt.close(fig)
    return [p1, p2]
