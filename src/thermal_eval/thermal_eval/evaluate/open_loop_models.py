"""Every model of the project as a generic ``evaluate`` model (the contract of :mod:`model_selection`).

Each one chooses its inputs and hyper-parameters on the training rows only, by walk-forward
(expanding folds, or the chronological 60/40 split TALC's order selection uses), and then
predicts open loop from temperatures (and, for the ``*_inputs`` variants, machine inputs):

- ``lagged_ridge`` / ``lagged_ridge_inputs``: ridge on the temperatures and low-pass copies
  (:mod:`talc_model.open_loop.lagged_temperature_model`, time constants and penalty by walk-forward);
- ``arx_simulation`` / ``arx_simulation_inputs``: TALC's ARX on a 5-min grid, inputs = medoid
  sensors of k-means groups (k chosen), orders by MDL, simulated after the fit rows; held
  between grid samples; ``arx_subgrid``: the same evaluated between grid samples;
  ``arx_subgrid_gain_update``: the same open loop, whose adaptive row re-estimates the gain of
  each input's contribution from the probes (:mod:`talc_model.open_loop.probe_gain_update`);
- ``lagged_ridge_gain_update`` (opt-in): ``lagged_ridge`` whose adaptive row re-estimates the
  gain of each feature's contribution from the probes (docs/evaluate.md, "the three untried directions": it wins the
  training rows' walk-forward but not the held-out rows);
- ``characteristic_diagram``: a smoothed-grid diagram of 1-2 temperatures and their 1-h
  low-pass (medoid sensors or the channel's most correlated ones; inputs and grid refinement
  chosen on the training rows' last 40 %);
- ``gp_static``: the AGP's ARD-RBF GP on the medoid temperatures and 0.5-h / 2-h low-pass
  copies (thinned to <= 400 training points); opt-in (:data:`.opt_in.OPT_IN`: ``--also gp_static``).

Nothing here knows a dataset. No rclpy here.
"""
from __future__ import annotations

import numpy as np

from talc_model.arx.model import ArxOrders, RankDeficientError, fit_arx
from talc_model.cd.diagram import CharacteristicDiagram, fit_with_grid_refinement
from talc_model.agp.gaussian_process import ArdGaussianProcess
from talc_model.open_loop.lagged_temperature_model import (CANDIDATE_TAUS_S, DEFAULT_ALPHA_GRID, LaggedTemperatureModel,
                                                 default_tau_grid, exponential_filter, walk_forward_select)
from talc_model.arx.order_selection import select_orders
from talc_model.open_loop.probe_gain_update import lagged_contributions
from talc_model.open_loop.sensor_selection import sensor_groups, sensor_medoids
from thermal_eval.evaluate.baselines import LOWPASS_TAU_S
from thermal_eval.evaluate.spec import EvaluationData, input_scale
from thermal_eval.evaluate.model_selection import ModelFailure, ModelSpec

GRID_STEP_S = 300.0                       # TALC's model grid
NA_RANGE = (1, 2)
NB_RANGE = (1, 6)
GROUP_CANDIDATES = (2, 3, 4, 6, 8, 10, 12)
CD_TAU_S = 3600.0
GP_TAUS_S = (1800.0, 7200.0)
GP_MAX_POINTS = 400


def _inputs(data: EvaluationData) -> np.ndarray:
    if data.inputs is None:
        raise ModelFailure("the recording has no machine input columns (name them with --inputs)")
    scales = [input_scale(data.inputs[:, j]) for j in range(data.inputs.shape[1])]
    return data.inputs / np.asarray(scales)


# ----------------------------------------------------------------------------- lagged ridge

def _lagged_select(with_inputs: bool, tau_grid=None, alpha_grid=DEFAULT_ALPHA_GRID):
    def select(data, channel, n_fit):
        exo = _inputs(data) if with_inputs else None
        sel = walk_forward_select(data.time_s, data.temperatures, data.displacement_um[channel], n_fit,
                                  list(tau_grid or default_tau_grid()), alpha_grid, n_folds=4, exogenous=exo,
                                  exogenous_taus_s=CANDIDATE_TAUS_S if with_inputs else ())
        return {"taus_s": list(sel.taus_s), "alpha": sel.alpha, "walk_forward_mae_um": round(sel.best_mae, 3),
                "walk_forward_fold_mae_um": [round(v, 3) for v in sel.fold_mae]}
    return select


def _lagged_predict(with_inputs: bool):
    def predict(data, channel, params, n_fit):
        exo = _inputs(data) if with_inputs else None
        m = LaggedTemperatureModel(tuple(params["taus_s"]), params["alpha"],
                                   CANDIDATE_TAUS_S if with_inputs else ())
        m.fit_recording(data.time_s[:n_fit], data.temperatures[:n_fit], data.displacement_um[channel][:n_fit],
                        None if exo is None else exo[:n_fit])
        return m.predict_recording(data.time_s, data.temperatures, exo)
    return predict


def _lagged_contributions(data, channel, params, n_fit):
    m = LaggedTemperatureModel(tuple(params["taus_s"]), params["alpha"])
    m.fit_recording(data.time_s[:n_fit], data.temperatures[:n_fit], data.displacement_um[channel][:n_fit])
    return lagged_contributions(m, m.features(data.time_s, data.temperatures))


# ----------------------------------------------------------------------------- ARX (TALC's model class)

def _grid(data: EvaluationData) -> tuple[np.ndarray, int]:
    step = max(1, int(round(GRID_STEP_S / float(np.median(np.diff(data.time_s))))))
    return np.arange(0, len(data), step), step


def _arx_rows(data: EvaluationData, names: list[str], with_inputs: bool) -> np.ndarray:
    cols = [data.sensors.index(s) for s in names]
    u = data.temperatures[:, cols] - data.temperatures[0, cols]
    return np.column_stack([u, _inputs(data)]) if with_inputs else u


def subgrid_prediction(model, u_rows: np.ndarray, grid: np.ndarray, pred_grid: np.ndarray, first: int) -> np.ndarray:
    """Rows from grid index ``first`` on, evaluated between the grid samples instead of held.

    A row r after grid sample k gets y_k + f (y~_{k+1}(r) - y_k), f = (t_r - t_k) / step, where
    y~_{k+1}(r) is the model's next grid value computed with the inputs of row r in place of those
    of grid sample k+1 (only the b_0 terms change). It uses nothing later than row r.

    ``u_rows``: inputs at every row (N x m); ``grid``: row index of each grid sample;
    ``pred_grid``: outputs on the grid (measured before ``first``, simulated after).
    """
    n = u_rows.shape[0]
    step = int(grid[1] - grid[0]) if grid.size > 1 else 1
    o = model.orders
    out = np.full(n, np.nan)
    u_grid = u_rows[grid]
    g_rows = np.arange(n) // step                  # grid index at or before each row
    rows = np.arange(grid[first], n)
    k = g_rows[rows]
    out[rows] = pred_grid[k]                        # grid rows (and the fallback for nk > 0)
    if o.nk != 0:
        return out
    nxt = k + 1                                     # the grid sample being approached
    val = np.full(rows.size, model.c)
    for i in range(1, o.na + 1):
        val -= model.a[i - 1] * pred_grid[nxt - i]
    for j, bj in enumerate(model.b):
        for lag in range(1, bj.size):
            val += bj[lag] * u_grid[nxt - lag, j]
        if bj.size:
            val += bj[0] * u_rows[rows, j]
    frac = (rows - grid[k]) / float(step)
    inside = frac > 0
    out[rows[inside]] = pred_grid[k[inside]] + frac[inside] * (val[inside] - pred_grid[k[inside]])
    return out


def _arx_select(with_inputs: bool, groups=GROUP_CANDIDATES):
    def select(data, channel, n_fit):
        grid, _ = _grid(data)
        g = int(np.sum(grid < n_fit))
        if g < 20:
            raise ModelFailure(f"{n_fit} fit rows give {g} samples of the {GRID_STEP_S:.0f}-s grid, need >= 20")
        y = data.displacement_um[channel][grid]
        m = len(data.sensors)
        best, scores = None, {}
        for k in [k for k in groups if k <= m] or [m]:
            names = sensor_medoids(data.temperatures[:n_fit], k, data.sensors)
            u = _arx_rows(data, names, with_inputs)[grid]
            try:
                sel = select_orders(y[:g], u[:g], NA_RANGE, NB_RANGE, criterion="mdl", train_fraction=0.6)
            except (RankDeficientError, ValueError) as exc:
                scores[",".join(names)] = f"failed: {exc}"
                continue
            scores[",".join(names)] = round(float(sel.validation_rms), 3)
            if best is None or sel.validation_rms < best[0]:
                best = (float(sel.validation_rms), names, sel)
        if best is None:
            raise ModelFailure(f"no input set gives an identifiable ARX model on the training rows ({scores})")
        rms, names, sel = best
        return {"inputs": list(names), "na": int(sel.orders.na), "nb": [int(b) for b in sel.orders.nb],
                "orders": sel.orders, "training_validation_rms_um": round(rms, 3), "input_sets": scores}
    return select


def fit_guarded(y: np.ndarray, u: np.ndarray, orders):
    """The chosen orders fitted as TALC's order selection keeps them (:func:`select_orders`'s
    refit rule): on every fit sample if that model is stable, else on the first 60 % it was
    selected on (an unstable refit would diverge in simulation)."""
    start = ArxOrders(NA_RANGE[1], (NB_RANGE[1],) * u.shape[1], orders.nk, orders.intercept).max_lag
    try:
        full = fit_arx(y, u, orders, start=start)
        if full.is_stable(0.0, False):
            return full
    except RankDeficientError:
        pass
    return fit_arx(y, u, orders, start=start, stop=int(round(0.6 * y.size)))


def _arx_fit(data, channel, params, n_fit, with_inputs):
    """The chosen ARX fitted on rows < n_fit: (model, grid, step, g, y on the grid, inputs by row)."""
    grid, step = _grid(data)
    g = int(np.sum(grid < n_fit))
    y = data.displacement_um[channel][grid]
    u_rows = _arx_rows(data, params["inputs"], with_inputs)
    try:
        model = fit_guarded(y[:g], u_rows[grid][:g], params["orders"])
    except RankDeficientError as exc:
        raise ModelFailure(f"ARX unidentifiable on rows < {n_fit}: {exc}") from None
    return model, grid, step, g, y, u_rows


def _arx_predict(with_inputs: bool, subgrid: bool):
    def predict(data, channel, params, n_fit):
        model, grid, step, g, y, u_rows = _arx_fit(data, channel, params, n_fit, with_inputs)
        pred_grid = model.simulate(u_rows[grid], y[:g], g)
        pred_grid[:g] = y[:g]
        if subgrid:
            pred = subgrid_prediction(model, u_rows, grid, pred_grid, g - 1)
            pred[:grid[g - 1]] = pred_grid[np.arange(grid[g - 1]) // step]
            return pred
        return pred_grid[np.minimum(np.arange(len(data)) // step, grid.size - 1)]
    return predict


def arx_contributions(model, u_grid: np.ndarray, g: int) -> np.ndarray:
    """Each input's share of the simulation from grid sample ``g`` (grid x inputs, 0 before g):
    the model simulated on that input alone from a zero history, minus the zero-input run (the
    intercept's). By linearity they sum with the zero-input run from the measured history to the
    full simulation."""
    zero_u = np.zeros_like(u_grid)
    hist = np.zeros(g)
    base = model.simulate(zero_u, hist, g)
    out = np.zeros(u_grid.shape)
    for j in range(u_grid.shape[1]):
        uj = zero_u.copy()
        uj[:, j] = u_grid[:, j]
        out[g:, j] = (model.simulate(uj, hist, g) - base)[g:]
    return out


def _arx_contributions(with_inputs: bool):
    def contributions(data, channel, params, n_fit):
        model, grid, step, g, _, u_rows = _arx_fit(data, channel, params, n_fit, with_inputs)
        per_grid = arx_contributions(model, u_rows[grid], g)
        return per_grid[np.minimum(np.arange(len(data)) // step, grid.size - 1)]   # held between samples
    return contributions


# ----------------------------------------------------------------------------- characteristic diagram

def _cd_features(data, names):
    cols = [data.sensors.index(s) for s in names]
    d = data.temperatures[:, cols] - data.temperatures[0, cols]
    return np.column_stack([d, exponential_filter(data.time_s, d, CD_TAU_S)])


#: sensors most correlated with a channel that the diagram also tries, alone and in pairs
CD_CORRELATED = 3


def _cd_candidates(data, y: np.ndarray, n_fit: int) -> list[list[str]]:
    """Input sets of the diagram: the medoid sensors of 1 and 2 k-means groups (the machine's
    temperature fields), and the :data:`CD_CORRELATED` sensors most correlated with this channel
    on the fit rows, alone and in pairs (a channel driven by one part of the machine, which a
    medoid of the whole may miss)."""
    sets = [sensor_medoids(data.temperatures[:n_fit], k, data.sensors) for k in (1, 2) if k <= len(data.sensors)]
    t, ok = data.temperatures[:n_fit], np.isfinite(y[:n_fit])
    with np.errstate(all="ignore"):
        r = np.array([abs(np.corrcoef(t[ok, j], y[:n_fit][ok])[0, 1]) for j in range(t.shape[1])])
    top = [data.sensors[j] for j in np.argsort(-np.nan_to_num(r))[:CD_CORRELATED]]
    sets += [[a] for a in top] + [[a, b] for i, a in enumerate(top) for b in top[i + 1:]]
    out: list[list[str]] = []
    for c in sets:
        if sorted(c) not in [sorted(o) for o in out]:
            out.append(list(c))
    return out


def _cd_select(data, channel, n_fit):
    """The input set and grid with the lowest validation RMSE on the last 40 % of the fit rows."""
    y = data.displacement_um[channel]
    split = int(0.6 * n_fit)
    best = None
    ok = np.isfinite(y[:n_fit])
    tr, va = np.flatnonzero(ok[:split]), split + np.flatnonzero(ok[split:n_fit])
    for names in _cd_candidates(data, y, split):
        x = _cd_features(data, names)
        cd, hist = fit_with_grid_refinement(x[tr], y[tr], x[va], y[va], max_intervals=8 if len(names) == 2 else 16)
        err = min(h["val_rmse"] for h in hist)
        if best is None or err < best[0]:
            best = (err, names, int(cd.n_intervals))
    return {"inputs": best[1], "n_intervals": best[2], "training_validation_rms_um": round(best[0], 3)}


def _cd_predict(data, channel, params, n_fit):
    y = data.displacement_um[channel]
    x = _cd_features(data, params["inputs"])
    ok = np.flatnonzero(np.isfinite(y[:n_fit]))
    cd = CharacteristicDiagram(n_intervals=params["n_intervals"]).fit(x[ok], y[ok])
    return cd.predict(x)


# ----------------------------------------------------------------------------- static GP

def gp_features(data: EvaluationData, names: list[str]) -> np.ndarray:
    cols = [data.sensors.index(s) for s in names]
    d = data.temperatures[:, cols] - data.temperatures[0, cols]
    return np.column_stack([d] + [exponential_filter(data.time_s, d, tau) for tau in GP_TAUS_S])


def _gp_select(data, channel, n_fit):
    """One medoid per unique sensor group (the AGP's WCSS elbow on the fit rows)."""
    k = sensor_groups(data.temperatures[:n_fit]).n_groups
    return {"inputs": sensor_medoids(data.temperatures[:n_fit], k, data.sensors), "sensor_groups": k}


def gp_fit_predict(data: EvaluationData, channel: str, params: dict, n_fit: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and predictive std of the GP fitted on (thinned) rows < n_fit."""
    y = data.displacement_um[channel]
    x = gp_features(data, params["inputs"])
    ok = np.flatnonzero(np.isfinite(y[:n_fit]))
    sub = ok[np.unique(np.linspace(0, ok.size - 1, min(GP_MAX_POINTS, ok.size)).round().astype(int))]
    gp = ArdGaussianProcess().fit(x[sub], y[sub])
    return gp.predict(x)


def _gp_predict(data, channel, params, n_fit):
    return gp_fit_predict(data, channel, params, n_fit)[0]


MODELS = [
    ModelSpec("lagged_ridge", "model", "ridge on temperatures + low-pass copies", _lagged_select(False),
              _lagged_predict(False)),
    ModelSpec("lagged_ridge_inputs", "model", "lagged ridge + machine inputs", _lagged_select(True),
              _lagged_predict(True), needs_inputs=True),
    ModelSpec("lagged_ridge_gain_update", "model", "lagged_ridge; adaptive: probes re-estimate each feature's gain",
              _lagged_select(False), _lagged_predict(False), contributions=_lagged_contributions),
    ModelSpec("lagged_ridge_refit", "model", "lagged_ridge; adaptive: re-fitted with the probe rows at each probing",
              _lagged_select(False), _lagged_predict(False)),
    ModelSpec("lowpass_ridge_refit", "model", "lowpass_ridge; adaptive: re-fitted with the probe rows at each probing",
              _lagged_select(False, [(LOWPASS_TAU_S,)]), _lagged_predict(False)),
    ModelSpec("arx_simulation", "model", "TALC's ARX, simulated (5-min grid held)", _arx_select(False),
              _arx_predict(False, False)),
    ModelSpec("arx_subgrid", "model", "TALC's ARX, simulated, evaluated between grid samples", _arx_select(False),
              _arx_predict(False, True)),
    ModelSpec("arx_subgrid_gain_update", "model", "arx_subgrid; adaptive: probes re-estimate each input's gain",
              _arx_select(False), _arx_predict(False, True), contributions=_arx_contributions(False)),
    ModelSpec("arx_subgrid_gain_forgetting", "model",
              "arx_subgrid_gain_update; older probe pairs fade (factor by walk-forward)", _arx_select(False), _arx_predict(False, True), contributions=_arx_contributions(False)),
    ModelSpec("arx_simulation_inputs", "model", "TALC's ARX + machine inputs", _arx_select(True),
              _arx_predict(True, False), needs_inputs=True),
    ModelSpec("characteristic_diagram", "model", "characteristic diagram of medoid temperatures + 1-h low-pass",
              _cd_select, _cd_predict),
    ModelSpec("gp_static", "model", "ARD-RBF GP on medoid temperatures + low-pass copies", _gp_select, _gp_predict),
]

def lagged_ridge_model(name: str, with_inputs: bool, tau_grid=None, alpha_grid=DEFAULT_ALPHA_GRID) -> ModelSpec:
    """The lagged ridge with its own walk-forward grids (a benchmark's smaller or larger search)."""
    return ModelSpec(name, "model", "lagged ridge" + (" + machine inputs" if with_inputs else ""),
                     _lagged_select(with_inputs, tau_grid, alpha_grid), _lagged_predict(with_inputs),
                     needs_inputs=with_inputs)


def arx_model(name: str, with_inputs: bool, subgrid: bool = False, groups=GROUP_CANDIDATES) -> ModelSpec:
    """TALC's ARX with its own candidate sensor-group counts (a benchmark's smaller or larger search)."""
    return ModelSpec(name, "model", "TALC's ARX, simulated" + (" + machine inputs" if with_inputs else ""),
                     _arx_select(with_inputs, tuple(groups)), _arx_predict(with_inputs, subgrid),
                     needs_inputs=with_inputs)
