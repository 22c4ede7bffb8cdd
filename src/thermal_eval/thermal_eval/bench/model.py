"""``thermal-comp bench model``: figures of the adaptive models.

TALC part (this module):

- ``talc.arx_refit_7x200h_ms``: one WLS refit of 7 MISO ARX models (n_a = 1, n_b = 10 for 3
  inputs, 31 parameters) on 200 h of 5-min history (2,400 samples), median of repeats;
  ``talc.statsmodels_wls_7x200h_ms`` the same fits with statsmodels ``WLS`` as the peer,
  ``talc.refit_speedup_vs_statsmodels`` their ratio and ``talc.refit_max_param_diff`` the
  largest parameter difference between the two (they solve the same problem);
- ``talc.arx_ols_fit_7x200h_ms`` / ``talc.sysidentpy_frols_7x200h_ms``: the same 7 fits
  unweighted (n_k = 1 and a constant, 32 parameters) with our ``fit_arx`` and with
  sysidentpy's FROLS keeping every regressor, ``talc.fit_speedup_vs_sysidentpy`` their
  ratio, ``talc.sysidentpy_max_prediction_diff_um`` the largest one-step prediction difference;
- ``talc.order_selection_7x200h_s``: MDL order selection over n_a <= 1, n_b <= 10 (coordinate
  search) for 7 components on the same history;
- ``order_selection.<case>.*``: one order selection batched versus per candidate
  (:mod:`thermal_eval.bench.order_selection`);
- ``fe.<static|fir|arx>.<y|z>.{rms_um,p99_um}``: the FE study of thesis §4.2 on the twin's
  ``fe-two-source`` (training) and ``fe-two-source-swapped`` (validation, simulation mode);
- ``talc.<scenario>.*``: the virtual experiment (TALC replayed on the twin, probing only
  when TALC asks, probe noise 0.25 um and 0.25 um resolution) on ``talc-178h-dry`` with the
  Table 6.4 parameters and ``talc-144h-mwf`` with Table 6.6, printed like Tables 6.5 / 6.7,
  and on ``load-case-A`` .. ``D`` with the Table 6.3 sets (``talc.<case>.table_6_3.*``);
  the P99 are taken over the compensation part (after the calibration phase).

The AGP / characteristic-diagram figures come from :func:`thermal_eval.bench.agp_cd.figures`
and are merged into the same dict.
"""
from __future__ import annotations

import math
import pathlib
import statistics
import time
from typing import Any, Callable

import numpy as np
from tqdm import tqdm

from thermal_comp_common import metrics
from thermal_comp_common.runtime.blas_threads import single_thread_blas
from thermal_comp_common.components import ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS
from talc_model.arx.model import ArxOrders, fit_arx, regression_matrix
from talc_model.arx.order_selection import select_orders
from talc_model.talc.model import TalcModel
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate
from thermal_twin.sim.synthetic_plant import make_plant, probe_noise_std

from thermal_eval.bench.order_selection import order_selection_speed
from thermal_eval.replay.virtual_experiment import plot_virtual_experiment, probe_noise_by_component, run_virtual_experiment

TALC_INPUTS = ["ambient", "ws_mwf", "c_coolant_delta"]     # the thesis's three temperatures
# probe noise (k=1) of the sphere cycle, thesis Table 5.4 (reproduced by probe_cycle):
# U(k=2) 0.4-0.6 um on linear errors and 2.3-2.6 um/m on angular ones
from thermal_eval.replay.summary import PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM  # noqa: E402,F401  Table 5.4, defined once
TALC_RUNS = (("talc-178h-dry", "table_6_4_178h"), ("talc-144h-mwf", "table_6_6_144h_mwf"))
LOAD_CASES = ("load-case-A", "load-case-B", "load-case-C", "load-case-D")


def _round(v: float, nd: int = 3) -> float:
    return round(float(v), nd) if math.isfinite(v) else float(v)


def _recording(machine: str, scenario: str, hours: float | None = None, seed: int = 0):
    return simulate(machine, make_timeline(machine, scenario, hours=hours, seed=seed), seed=seed).to_recording()


# ------------------------------------------------------------------ refit speed
def _time_alternately(ours: Callable[[], Any], peer: Callable[[], Any], repeats: int):
    """Run ``ours`` and ``peer`` alternately ``repeats`` times; (last results, wall times)."""
    t_ours, t_peer = [], []
    a = b = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        a = ours()
        t_ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        b = peer()
        t_peer.append(time.perf_counter() - t0)
    return a, b, t_ours, t_peer


def _refit_problem() -> tuple[np.ndarray, list[np.ndarray]]:
    """200 h of 5-min history of the synthetic plant: the three TALC input deltas and the 7
    errors with probe noise (seeded)."""
    plant = make_plant(hours=200.0, step_s=300.0, seed=11)
    t = plant.temperatures
    u = np.column_stack([t["ambient"] - t["ambient"][0], t["ws"] - t["ws"][0],
                         (t["c_coolant_out"] - t["c_coolant_in"]) - (t["c_coolant_out"][0] - t["c_coolant_in"][0])])
    rng = np.random.default_rng(0)
    noise = probe_noise_std()
    return u, [plant.errors[c] + rng.normal(0, noise[c], u.shape[0]) for c in FIVE_AXIS_COMPONENTS]


def refit_speed(repeats: int = 5) -> dict[str, Any]:
    """7 ARX WLS refits on 200 h of 5-min history, ours versus statsmodels WLS."""
    import statsmodels.api as sm  # heavy: statsmodels only for this comparison
    u, ys = _refit_problem()
    measured = np.zeros(u.shape[0], bool)
    measured[::24] = True                            # a probe every 2 h
    weights = np.where(measured, 1.0, 0.05)           # TALC's low weight on predicted samples
    orders = ArxOrders(1, (10, 10, 10))

    def ours():
        return [fit_arx(y, u, orders, weights) for y in ys]

    def peer():
        out = []
        for y in ys:
            phi, target, rows = regression_matrix(y, u, orders)
            out.append(sm.WLS(target, phi, weights=weights[rows]).fit())
        return out

    with single_thread_blas():
        a, b, t_ours, t_peer = _time_alternately(ours, peer, repeats)
    diff = max(float(np.max(np.abs(m.theta - r.params))) for m, r in zip(a, b))
    t0 = time.perf_counter()
    for y in ys:
        select_orders(y, u, (1, 1), (1, 10), weights=weights, measured=measured, exhaustive_limit=200)
    t_sel = time.perf_counter() - t0
    mo, mp = statistics.median(t_ours), statistics.median(t_peer)
    return {"talc.arx_refit_7x200h_ms": _round(1e3 * mo, 2),
            "talc.statsmodels_wls_7x200h_ms": _round(1e3 * mp, 2),
            "talc.refit_speedup_vs_statsmodels": _round(mp / mo, 2),
            "talc.refit_max_param_diff": float(f"{diff:.3g}"),
            "talc.order_selection_7x200h_s": _round(t_sel, 2)}


def sysidentpy_comparison(repeats: int = 3) -> dict[str, Any]:
    """7 ordinary least-squares ARX fits on 200 h of 5-min history, ours versus sysidentpy.

    The same model in both: y(k-1), inputs at lags 1..10 (sysidentpy's lags start at 1, so our
    n_k = 1) and a constant (sysidentpy's degree-1 polynomial basis has one), 32 parameters,
    unweighted (sysidentpy has no sample weights). sysidentpy's FROLS with
    ``order_selection=False`` and ``n_terms`` = all 32 candidates orthogonalises and keeps every
    regressor, then ``LeastSquares`` estimates them. The agreement figure is the largest
    difference of the two models' one-step-ahead predictions over the history.
    """
    # heavy: sysidentpy only for this comparison
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    u, ys = _refit_problem()
    orders = ArxOrders(1, (10, 10, 10), nk=1, intercept=True)

    def ours():
        return [fit_arx(y, u, orders) for y in ys]

    def peer():
        out = []
        for y in ys:
            m = FROLS(order_selection=False, n_terms=orders.n_params, ylag=1, xlag=[list(range(1, 11))] * 3,
                      estimator=LeastSquares(), basis_function=Polynomial(degree=1))
            m.fit(X=u, y=y.reshape(-1, 1))
            out.append(m)
        return out

    with single_thread_blas(), np.errstate(all="ignore"):
        a, b, t_ours, t_peer = _time_alternately(ours, peer, repeats)
        diff = 0.0
        for y, mo, mp in zip(ys, a, b):
            phi, _, rows = regression_matrix(y, u, orders)
            pred_peer = np.asarray(mp.predict(X=u, y=y.reshape(-1, 1), steps_ahead=1)).ravel()
            diff = max(diff, float(np.max(np.abs(pred_peer[rows] - phi @ mo.theta))))
    mo_, mp_ = statistics.median(t_ours), statistics.median(t_peer)
    return {"talc.arx_ols_fit_7x200h_ms": _round(1e3 * mo_, 2),
            "talc.sysidentpy_frols_7x200h_ms": _round(1e3 * mp_, 2),
            "talc.fit_speedup_vs_sysidentpy": _round(mp_ / mo_, 2),
            "talc.sysidentpy_max_prediction_diff_um": float(f"{diff:.3g}")}


# ------------------------------------------------------------------ FE study (thesis §4.2)
def fe_study() -> dict[str, Any]:
    """Static regression, FIR and ARX on fe-two-source, validated on the swapped loads."""
    train = _recording("fe_three_body", "fe-two-source")
    valid = _recording("fe_three_body", "fe-two-source-swapped")

    def signals(rec):
        u = np.column_stack([rec.columns["s1_c"] - rec.columns["s1_c"][0],
                             rec.columns["s2_c"] - rec.columns["s2_c"][0]])
        return u, {ax: rec.columns[f"drift_{ax}_um"] - rec.columns[f"drift_{ax}_um"][0] for ax in ("y", "z")}

    u_t, y_t = signals(train)
    u_v, y_v = signals(valid)
    out: dict[str, Any] = {}
    first = 10                                        # every model judged on the same samples
    for ax in ("y", "z"):
        models = {
            "static": fit_arx(y_t[ax], u_t, ArxOrders(0, (1, 1), intercept=True)),
            "fir": select_orders(y_t[ax], u_t, (0, 0), (1, 10), intercept=True).model,
            "arx": select_orders(y_t[ax], u_t, (1, 1), (1, 10)).model,
        }
        for name, m in models.items():
            pred = m.simulate(u_v, np.zeros(u_v.shape[0]), max(m.orders.max_lag, 1))
            e, p = y_v[ax][first:], pred[first:]
            out[f"fe.{name}.{ax}.rms_um"] = _round(metrics.e_rms(e, p))
            out[f"fe.{name}.{ax}.p99_um"] = _round(metrics.p99(e, p))
            out[f"fe.{name}.{ax}.orders"] = f"na={m.orders.na} nb={list(m.orders.nb)}"
    return out


# ------------------------------------------------------------------ virtual experiments
def talc_replay(scenario: str, config: dict, hours: float | None, out_dir: pathlib.Path | None,
                key: str) -> tuple[dict[str, Any], str]:
    """TALC replayed on a twin scenario; returns figures and a Table 6.5-style text."""
    rec = _recording("nmv5000", scenario, hours=hours)
    cfg = {"input_names": TALC_INPUTS}
    cfg.update(config)
    model = TalcModel(cfg)
    t0 = time.perf_counter()
    noise = probe_noise_by_component(model.component_names, PROBE_NOISE_LINEAR_UM,
                                     PROBE_NOISE_ANGULAR_UM_PER_M, model.config.angular_components)
    res = run_virtual_experiment(rec, model, probe_noise_um=noise,
                                 probe_resolution_um=PROBE_RESOLUTION_UM, compute_metrics=False)
    wall = time.perf_counter() - t0
    phase = np.asarray(res.phase)
    comp = phase != "calibration"
    st = model.status(float(res.time_s[-1]))
    out: dict[str, Any] = {f"{key}.q_prod_pct": _round(st.q_prod_pct, 2),
                           f"{key}.calibration_h": _round(float(res.time_s[comp][0] - res.time_s[0]) / 3600.0, 2)
                           if comp.any() else math.nan,
                           f"{key}.no_good_phases": st.no_good_phases,
                           f"{key}.parameter_updates": st.parameter_updates,
                           f"{key}.replay_s": _round(wall, 1)}
    p99c, p99u = {}, {}
    if comp.any():
        for c in res.components:
            p99c[c] = metrics.p99(res.true[c][comp], res.predicted[c][comp])
            p99u[c] = metrics.p99(res.true[c][comp], np.zeros(int(comp.sum())))
            out[f"{key}.{c}.p99_um"] = _round(p99c[c], 2)
            out[f"{key}.{c}.p99_uncompensated_um"] = _round(p99u[c], 2)
    lin = [c for c in res.components if c not in ANGULAR_COMPONENTS]
    ang = [c for c in res.components if c in ANGULAR_COMPONENTS]
    out[f"{key}.p99_lin_um"] = _round(metrics.p99_group(p99c, lin), 2)
    out[f"{key}.p99_ang_um_per_m"] = _round(metrics.p99_group(p99c, ang), 2)
    lines = [f"{scenario} ({config.get('preset', 'custom')}): Q_prod {st.q_prod_pct:.2f} %, "
             f"CP {out[f'{key}.calibration_h']} h, {st.no_good_phases} no-good phases, "
             f"{st.parameter_updates} updates",
             "".ljust(20) + "".join(c.rjust(9) for c in p99c),
             "P99 uncompensated".ljust(20) + "".join(f"{p99u[c]:9.1f}" for c in p99c),
             "P99 compensated".ljust(20) + "".join(f"{p99c[c]:9.1f}" for c in p99c),
             "Reduction %".ljust(20) + "".join(f"{100 * (1 - p99c[c] / p99u[c]):9.1f}" if p99u[c] > 0 else
                                                 "      n/a" for c in p99c)]
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        plot_virtual_experiment(res, out_dir / f"talc_{scenario}.png", title=scenario)
    return out, "\n".join(lines)


def _order_selection_speed(quick: bool) -> dict[str, Any]:
    return order_selection_speed(1 if quick else 3)


def _agp_cd_figures(args) -> dict[str, Any]:
    """Hook: the AGP / CD figures (thermal_eval.bench.agp_cd.figures)."""
    try:
        from thermal_eval.bench import agp_cd as bench_agp_cd  # heavy: scikit-learn only for these figures
    except ImportError:
        return {}
    return bench_agp_cd.figures(args)


def run(args) -> dict[str, Any]:
    """All figures; ``args.quick`` shortens the replays, ``args.out_dir`` receives PNGs."""
    quick = bool(getattr(args, "quick", False))
    out_dir = getattr(args, "out_dir", None)
    out_dir = pathlib.Path(out_dir) if out_dir else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    jobs: list[tuple[str, Callable[[], tuple[dict, str | None]]]] = [
        ("ARX refit speed", lambda: (refit_speed(2 if quick else 5), None)),
        ("ARX vs sysidentpy", lambda: (sysidentpy_comparison(1 if quick else 3), None)),
        ("order selection batched vs per candidate", lambda: (_order_selection_speed(quick), None)),
        ("FE study", lambda: (fe_study(), None)),
    ]
    for scen, preset in TALC_RUNS:
        jobs.append((f"TALC {scen}", lambda s=scen, p=preset: talc_replay(
            s, {"preset": p}, 48.0 if quick else None, out_dir, f"talc.{s}")))
    for case in LOAD_CASES[: 1 if quick else None]:
        jobs.append((f"TALC {case}", lambda c=case: talc_replay(
            c, {"preset": f"table_6_3_{c[-1]}"}, 48.0 if quick else None, out_dir, f"talc.{c}.table_6_3")))
    out: dict[str, Any] = {}
    tables = []
    with tqdm(total=len(jobs), desc="bench talc", unit="part") as bar:
        for name, job in jobs:
            bar.set_postfix_str(name)
            figs, table = job()
            out.update(figs)
            if table:
                tables.append(table)
            bar.update(1)
    for t in tables:
        print(t, flush=True)
    out.update(_agp_cd_figures(args))
    return out
