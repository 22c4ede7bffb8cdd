"""Benchmark of the probe cycle: speed of the core and repeatability of the measurement.

``thermal-comp bench probe [--quick] [--out-dir DIR]``. It runs N sphere cycles (200, or
30 with --quick) on the artefact model of a warm, steady machine, with the probe's scatter
and 1 um resolution, and reports:

* the core's speed: one centre fit and one whole cycle (plan, 25 touches on the forward
  model, 5 fits, eq. 5.4-5.10), in ms;
* U(k=2) of every error over the N cycles, next to the uncertainty the cycle reports
  (fit covariance and probe model) and Table 5.4 of the thesis;
* the guide-bush cycle's U(k=2) over the same number of cycles.

It writes ``probe_repeatability.png`` (scatter of every component over the cycles, with
the reported +-U band) to the output folder.
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
from tqdm import tqdm

from thermal_twin.machine.artefact_geometry import (ARTEFACT_GUIDE_BUSH, DEFAULT_GEOMETRY,
                                            SPHERE_COMPONENTS)

from probe_cycle.cycle_plan import plan_sphere_cycle
from probe_cycle.probe_backend import ArtefactModelBackend
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine
from probe_cycle.sphere_fit import fit_sphere_centre

TABLE_5_4_U_K2 = {"E_X0C": 0.4, "E_Y0C": 0.5, "E_Z0T": 0.4, "E_R0T": 0.6, "E_A0C": 2.3,
                  "E_B0C": 2.5, "E_C0C": 2.6}
WARM_ERRORS = {"E_X0C": 4.0, "E_Y0C": 18.0, "E_Z0T": -21.0, "E_R0T": 6.0, "E_A0C": 12.0,
               "E_B0C": -7.0, "E_C0C": 3.0, "GB_X": 14.0}


def run(args: argparse.Namespace | None = None) -> dict:
    quick = bool(getattr(args, "quick", False))
    out_dir = pathlib.Path(getattr(args, "out_dir", None) or "bench_out")
    out_dir.mkdir(parents=True, exist_ok=True)
    n_cycles = 30 if quick else 200
    rng = np.random.default_rng(5)
    engine = ProbeCycleEngine(DEFAULT_GEOMETRY)
    backend = ArtefactModelBackend(errors=WARM_ERRORS, geometry=DEFAULT_GEOMETRY, rng=rng)

    # one centre fit
    plan = plan_sphere_cycle(DEFAULT_GEOMETRY)
    moves = plan.moves_of_group(0)
    pts = np.array([backend.touch(m).position_mm for m in moves])
    dirs = np.array([m.direction for m in moves])
    reps = 50 if quick else 300
    t0 = time.perf_counter()
    for _ in range(reps):
        fit_sphere_centre(pts, dirs, plan.contact_radius_mm, engine.sphere_point_sigma_um,
                          np.asarray(plan.nominal_centres_mm[0]))
    fit_ms = (time.perf_counter() - t0) / reps * 1e3

    assert engine.run(GoalSpec(set_reference=True), backend).success
    values, reported = [], []
    t0 = time.perf_counter()
    for _ in tqdm(range(n_cycles), desc="sphere cycles", unit="cycle"):
        r = engine.run(GoalSpec(), backend)
        if not r.success:
            raise RuntimeError(f"cycle failed on a steady machine: {r.message}")
        values.append(r.errors.values)
        reported.append(r.errors.uncertainties)
    cycle_ms = (time.perf_counter() - t0) / n_cycles * 1e3
    values, reported = np.array(values), np.array(reported)

    gb = []
    engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
    for _ in range(n_cycles):
        gb.append(engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend).errors.values[0])

    u_k2 = {c: round(float(2 * values[:, i].std(ddof=1)), 3)
            for i, c in enumerate(SPHERE_COMPONENTS)}
    # the reported uncertainty includes the reference; one cycle's share is 1/sqrt(2) of it
    u_k2_reported = {c: round(float(2 * reported[:, i].mean() / np.sqrt(2)), 3)
                     for i, c in enumerate(SPHERE_COMPONENTS)}
    _plot(values, reported, out_dir / "probe_repeatability.png")
    return {
        "cycles": n_cycles,
        "centre_fit_ms": round(fit_ms, 3),
        "sphere_cycle_core_ms": round(cycle_ms, 2),
        "U_k2_measured": u_k2,
        "U_k2_reported_per_cycle": u_k2_reported,
        "U_k2_table_5_4": TABLE_5_4_U_K2,
        "guide_bush_U_k2_um": round(float(2 * np.std(gb, ddof=1)), 3),
        "plot": str(out_dir / "probe_repeatability.png"),
    }


def _plot(values: np.ndarray, reported: np.ndarray, path: pathlib.Path) -> None:
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    fig, axes = plt.subplots(7, 1, figsize=(8, 12), sharex=True)
    k = np.arange(1, len(values) + 1)
    for i, (ax, c) in enumerate(zip(axes, SPHERE_COMPONENTS)):
        mean = values[:, i].mean()
        u = 2 * reported[:, i].mean() / np.sqrt(2)
        ax.plot(k, values[:, i], ".", ms=3)
        ax.axhspan(mean - u, mean + u, color="tab:orange", alpha=0.2,
                   label="reported U(k=2), one cycle")
        ax.set_ylabel(f"{c}\n[{'um/m' if c in ('E_A0C', 'E_B0C', 'E_C0C') else 'um'}]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title("Sphere cycles on a steady machine: scatter of the measured errors")
    axes[-1].set_xlabel("cycle")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
