"""The observer-style state update (talc_model.arx.observer) against the thesis's replacement of
the newest output: stable for n_a > 1 where the replacement diverges, the same as the
replacement for n_a = 1 with exact probes, and the covariance it keeps is a covariance."""
import json
import math

import numpy as np
import pytest

from talc_model.adaptive_model import PHASE_COMPENSATION
from talc_model.arx.model import ArxModel, ArxOrders
from talc_model.arx.observer import K_MIN, ObserverError, companion, observer_predictions, observer_update
from talc_model.talc.model import TalcModel

STEP = 300.0
POLES = (0.995, 0.99)          # two slow thermal time constants (8.3 h and 8.3 / 2 h at 5 min)


def _ambient(hours: float, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, STEP)
    amb = sum(rng.uniform(0.5, 2) * np.sin(2 * np.pi * t / (rng.uniform(4, 30) * 3600) + rng.uniform(0, 6))
              for _ in range(3))
    return amb - amb[0]


def _arx(poles, static_gain: float) -> ArxModel:
    a = np.poly(poles)[1:].real
    b0 = static_gain * (1 + a.sum())
    return ArxModel(ArxOrders(len(poles), (1,)), np.concatenate([a, [b0]]))


def _run(model_arx: ArxModel, plant_arx: ArxModel, state_update: str, hours: float = 96.0,
         noise_um: float = 0.25, seed: int = 0):
    """A TALC model holding ``model_arx`` (no parameter updates) probes a plant ``plant_arx``
    every 2 h; returns (true error, prediction in effect)."""
    amb = _ambient(hours)
    true = plant_arx.simulate(amb[:, None], np.zeros(plant_arx.orders.max_lag), plant_arx.orders.max_lag)
    true[: plant_arx.orders.max_lag] = 0.0
    cfg = {"component_names": ["E_X0C"], "angular_components": [], "input_names": ["amb"],
           "update_interval_h": math.inf, "acl_linear_um": math.inf, "state_update": state_update,
           "probe_noise_linear_um": noise_um, "hold_fallback": False}   # the observer alone
    m = TalcModel(cfg)
    m.models = {"E_X0C": model_arx}
    m.phase = PHASE_COMPENSATION
    rng = np.random.default_rng(seed)
    pred = np.zeros_like(true)
    for k in range(amb.size):
        t = k * STEP
        m.update_inputs(t, {"amb": float(amb[k])}, {})
        v, _ = m.predict(t)
        pred[k] = v["E_X0C"]
        if m.probe_due(t):
            meas = true[k] - v["E_X0C"] + rng.normal(0.0, noise_um)
            m.add_measurement(t, {"E_X0C": meas}, {"E_X0C": v["E_X0C"]})
            pred[k] = m.predict(t)[0]["E_X0C"]
    return true, pred, m


def test_replacing_the_newest_output_diverges_for_n_a_2_and_the_observer_does_not():
    plant = _arx(POLES, 4.0)
    model = _arx(POLES, 3.0)          # another unit: 25 % less gain than this one
    true, pred_replace, _ = _run(model, plant, "replace")
    true, pred_obs, m = _run(model, plant, "observer")
    scale = np.max(np.abs(true))
    assert np.max(np.abs(pred_replace)) > 100 * scale           # the switched system is unstable
    assert np.max(np.abs(pred_obs - true)) < 0.5 * scale         # the observer stays with the plant
    late = slice(true.size // 2, None)
    assert np.percentile(np.abs(pred_obs - true)[late], 99) < 0.25 * scale
    assert m.probing_cycles > 40
    p = m.observer["E_X0C"][1]
    assert np.allclose(p, p.T) and np.all(np.linalg.eigvalsh(p) >= -1e-12)


def test_for_n_a_1_and_exact_probes_the_observer_is_the_replacement():
    plant = _arx((0.99,), 4.0)
    model = _arx((0.99,), 3.0)
    _, pred_replace, _ = _run(model, plant, "replace", hours=24.0, noise_um=0.0)
    _, pred_obs, _ = _run(model, plant, "observer", hours=24.0, noise_um=0.0)
    assert np.allclose(pred_obs, pred_replace, atol=1e-9)


def test_gain_follows_the_innovations_and_has_a_floor():
    a = np.array([-0.99])
    r = 0.25 ** 2
    small, _ = observer_update(a, np.zeros((1, 1)), 24, 0.01, 0.01 ** 2, r)
    assert small[0] / 0.01 == pytest.approx(K_MIN)                  # a model that predicts its probes
    big, _ = observer_update(a, np.zeros((1, 1)), 24, 3.0, 9.0, r)
    assert big[0] / 3.0 == pytest.approx(1 - r / 9.0)                # prior variance = 9 - r
    half, _ = observer_update(a, np.zeros((1, 1)), 24, 3.0, 9.0, r, gain_scale=0.5)
    assert half[0] == pytest.approx(0.5 * big[0])


def test_n_a_2_correction_moves_the_whole_history_nearly_as_one():
    a = np.poly(POLES)[1:]
    corr, post = observer_update(a, np.zeros((2, 2)), 24, 2.0, 4.0, 0.0625)
    assert corr[0] > 0 and corr[1] / corr[0] > 0.9                 # slow poles: a shift, not a bend
    assert post[0, 0] < 0.0625


def test_bad_arguments_name_themselves():
    with pytest.raises(ObserverError, match="innovation"):
        observer_update(np.array([-0.9]), np.zeros((1, 1)), 1, math.nan, 1.0, 0.1)
    with pytest.raises(ObserverError, match="gain_scale"):
        observer_update(np.array([-0.9]), np.zeros((1, 1)), 1, 1.0, 1.0, 0.1, gain_scale=0.0)
    assert companion(np.array([0.5, -0.2])).tolist() == [[-0.5, 0.2], [1.0, 0.0]]


def test_observer_state_round_trips():
    _, _, m = _run(_arx(POLES, 3.0), _arx(POLES, 4.0), "observer", hours=12.0)
    back = TalcModel.from_state(json.loads(json.dumps(m.to_state())))
    assert back.observer["E_X0C"][0] == m.observer["E_X0C"][0]
    assert np.allclose(back.observer["E_X0C"][1], m.observer["E_X0C"][1])
    assert np.allclose(back.grid.x[: back.grid.n], m.grid.x[: m.grid.n], equal_nan=True)


@pytest.mark.parametrize("poles", [(0.97,), POLES])
def test_offline_observer_predictor_is_the_online_loop(poles):
    """observer_predictions (what update acceptance ranks candidate models by) gives, at every
    probe, the prediction the online loop had before that probe."""
    model, plant = _arx(poles, 3.0), _arx(poles, 4.0)
    _, _, m = _run(model, plant, "observer", hours=48.0)
    g = m.grid
    # the online loop's predictions before each probe: re-run it and read x before the update
    online = []
    amb = _ambient(48.0)
    cfg = dict(m.config.as_dict())
    twin = TalcModel(cfg)
    twin.models = {"E_X0C": model}
    twin.phase = PHASE_COMPENSATION
    for k in range(amb.size):
        twin.update_inputs(k * STEP, {"amb": float(amb[k])}, {})
        v, _ = twin.predict(k * STEP)
        if g.measured[k, 0]:
            online.append(v["E_X0C"])
            twin.add_measurement(k * STEP, {"E_X0C": float(g.y[k, 0]) - v["E_X0C"]}, {"E_X0C": v["E_X0C"]})
    lag = model.orders.max_lag      # the loop's history before its start: zeros, known exactly
    u = np.concatenate([np.zeros((lag, 1)), g.u[: g.n]])
    y = np.concatenate([np.zeros(lag), g.y[: g.n, 0]])
    meas = np.concatenate([np.zeros(lag, bool), g.measured[: g.n, 0]])
    pred = observer_predictions(model, u, y, lag, meas, 0.25 ** 2, m.config.uncertainty_window,
                                p_start=np.zeros((model.orders.na,) * 2))
    assert len(online) > 20
    assert np.allclose(pred[meas], online, atol=1e-9)


def test_update_acceptance_ranks_by_the_observer_predictor():
    """With the observer, the replacement predictor's ranking is not what the loop does: for an
    n_a = 2 model the replacement's error at the probes is far larger than the observer's."""
    model = _arx(POLES, 3.0)
    _, _, m = _run(model, _arx(POLES, 4.0), "observer", hours=48.0)
    m.t_last_update = None
    err_obs = m._predictor_error(model, 0, 48.0 * 3600.0)
    m.config.state_update = "replace"
    err_rep = m._predictor_error(model, 0, 48.0 * 3600.0)
    assert math.isfinite(err_obs) and err_obs < 0.5 * err_rep


def test_order_selection_can_score_with_the_observer():
    """select_with_state_updates scores candidates with the loop's observer predictor: the
    selection equals the per-candidate reference, and its validation RMS is the observer's,
    not the replacement's."""
    from talc_model.arx.observer import ObserverScoring
    from talc_model.arx.order_selection import _select_orders_reference, select_orders
    amb = _ambient(120.0)
    plant = _arx(POLES, 4.0)
    y = plant.simulate(amb[:, None], np.zeros(2), 2)
    y[:2] = 0.0
    y = y + np.random.default_rng(1).normal(0.0, 0.25, y.size)
    measured = np.zeros(y.size, bool)
    measured[::24] = True
    kw = dict(measured=measured, max_pole_radius=0.9995)
    obs = ObserverScoring(0.25 ** 2, 10)
    a = select_orders(y, amb, (1, 3), (1, 4), state_updates=obs, **kw)
    b = _select_orders_reference(y, amb, (1, 3), (1, 4), state_updates=obs, **kw)
    rep = select_orders(y, amb, (1, 3), (1, 4), state_updates=True, **kw)
    assert a.orders == b.orders and a.score == pytest.approx(b.score)
    assert a.validation_rms != pytest.approx(rep.validation_rms, rel=1e-3)


def test_talc_selects_with_the_state_update_it_runs():
    base = {"component_names": ["E_X0C"], "angular_components": [], "input_names": ["amb"],
            "select_with_state_updates": True}
    from talc_model.arx.observer import ObserverScoring
    m = TalcModel(base)
    assert m._scoring("E_X0C") is False                 # calibration phase: pure simulation
    m.phase = PHASE_COMPENSATION
    assert m._scoring("E_X0C") == ObserverScoring(0.25 ** 2, m.config.uncertainty_window)
    assert TalcModel({**base, "state_update": "replace"}, )._scoring("E_X0C") is False
    r = TalcModel({**base, "state_update": "replace"})
    r.phase = PHASE_COMPENSATION
    assert r._scoring("E_X0C") is True
