"""Probe-driven state update: schedule, no-good phases, the slow-error Kalman filter, bad input."""
import math

import numpy as np
import pytest

from talc_model.probing.probe_update import ProbeSchedule, ProbeUpdateError, q_prod_pct, run_probe_updates
from talc_model.loop.slow_error_filter import SlowErrorError, SlowErrorFilter

DT = 15.0


def _rows(hours: float) -> np.ndarray:
    return np.arange(0.0, hours * 3600.0, DT)


def test_probes_every_interval_from_the_end_of_the_previous_cycle():
    t = _rows(12)
    y = np.zeros(t.size)
    r = run_probe_updates(t, y, y, 1, ProbeSchedule(acl_um=math.inf), [SlowErrorFilter()])
    gaps = np.diff(t[r.probe_rows])
    # 7200 s + 95 s of probing, on the next 15-s row
    assert len(r.probe_rows) == 5 and np.all(gaps >= 7295.0) and np.all(gaps < 7295.0 + DT)
    assert t[r.probe_rows[0]] >= t[0] + 7295.0
    no_end = run_probe_updates(t, y, y, 1, ProbeSchedule(acl_um=math.inf, interval_from_cycle_end=False),
                               [SlowErrorFilter()])
    assert np.all(np.diff(t[no_end.probe_rows]) == 7200.0)


def test_an_exact_probe_cancels_a_constant_model_error_from_the_probe_on():
    t = _rows(6)
    pred = np.sin(t / 3000.0)
    y = pred + 3.0                                     # the model misses a constant 3 um
    flt = SlowErrorFilter(bias_time_constant_s=1e12, noise_ratio=0.0)
    r = run_probe_updates(t, y, pred, 1, ProbeSchedule(acl_um=math.inf), [flt])
    first = r.probe_rows[0]
    np.testing.assert_allclose(r.compensation[1:first + 1, 0], pred[1:first + 1])   # before: open loop
    np.testing.assert_allclose(r.compensation[first + 1:, 0], y[first + 1:], atol=1e-6)
    assert np.isnan(r.compensation[0, 0])              # the calibration row is not claimed


def test_the_slow_error_decays_with_its_time_constant_and_a_noisy_probe_is_trusted_less():
    t = _rows(6)
    pred = np.zeros(t.size)
    y = np.full(t.size, 2.0)
    tau = 3600.0
    r = run_probe_updates(t, y, pred, 1, ProbeSchedule(acl_um=math.inf), [SlowErrorFilter(tau, 0.0)])
    k = r.probe_rows[0]
    assert r.bias[k + 1, 0] == pytest.approx(2.0 * math.exp(-DT / tau))
    assert r.bias[k + 240, 0] == pytest.approx(2.0 * math.exp(-3600.0 / tau))  # one tau later: 2/e
    gains = []
    for ratio in (0.0, 1.0, 10.0):
        rr = run_probe_updates(t, y, pred, 1, ProbeSchedule(acl_um=math.inf), [SlowErrorFilter(tau, ratio)])
        gains.append(rr.bias[k + 1, 0] / (2.0 * math.exp(-DT / tau)))
    # variance before the first probe: 1 - exp(-2 * 7295 / tau) ~ 1, so the gain is ~1 / (1 + ratio)
    assert gains[0] == pytest.approx(1.0)
    assert gains[1] == pytest.approx(0.5, abs=0.01) and gains[2] == pytest.approx(1.0 / 11.0, abs=0.01)


def test_a_residual_beyond_the_acl_starts_one_no_good_phase_of_dense_probes():
    t = _rows(14)
    pred = np.zeros(t.size)
    y = np.where(t >= 3 * 3600.0, 2.0, 0.0)             # a 2-um step the model misses
    y = y + np.where(t >= 5 * 3600.0, 2.0, 0.0)         # and another one during the no-good phase
    sched = ProbeSchedule(acl_um=1.0)
    r = run_probe_updates(t, y, pred, 1, sched, [SlowErrorFilter(1e9, 0.0)])
    times = t[r.probe_rows]
    assert r.no_good_phases == 1                        # the second step falls inside the NG phase
    ng = np.flatnonzero((times > 3 * 3600.0))
    dense = np.diff(times[ng[0]:ng[0] + 13])
    assert np.all((dense >= 695.0) & (dense < 695.0 + DT))    # 12 probes at 10 min + 95 s
    assert np.diff(times[ng[0] + 12:ng[0] + 14])[0] >= 7295.0  # then back to every 2 h
    # with the thesis's 5 um the steps never start a no-good phase
    assert run_probe_updates(t, y, pred, 1, ProbeSchedule(acl_um=5.0), [SlowErrorFilter()]).no_good_phases == 0


def test_channels_share_one_schedule_and_any_channel_starts_a_no_good_phase():
    t = _rows(8)
    pred = np.zeros((t.size, 2))
    y = np.column_stack([np.zeros(t.size), np.where(t > 3600.0, 9.0, 0.0)])
    r = run_probe_updates(t, y, pred, 1, ProbeSchedule(), [SlowErrorFilter(), SlowErrorFilter(1e9, 0.0)])
    assert r.no_good_phases == 1 and r.compensation.shape == (t.size, 2)
    assert np.all(r.bias[1:, 0] == 0.0)                 # the channel without error is left alone


def test_bad_input_is_named():
    t = _rows(3)
    y = np.zeros(t.size)
    bad = y.copy()
    bad[100] = np.nan
    with pytest.raises(ProbeUpdateError, match="prediction_um: row 100"):
        run_probe_updates(t, y, bad, 1, ProbeSchedule(), [SlowErrorFilter()])
    with pytest.raises(ProbeUpdateError, match=r"true_um: row \d+ .*probing"):
        run_probe_updates(t, np.full(t.size, np.nan), y, 1, ProbeSchedule(), [SlowErrorFilter()])
    with pytest.raises(ProbeUpdateError, match="filters: 2 given for 1 channels"):
        run_probe_updates(t, y, y, 1, ProbeSchedule(), [SlowErrorFilter()] * 2)
    with pytest.raises(ProbeUpdateError, match="start/stop"):
        run_probe_updates(t, y, y, 0, ProbeSchedule(), [SlowErrorFilter()])
    with pytest.raises(ProbeUpdateError, match="acl_um: 0"):
        ProbeSchedule(acl_um=0)
    with pytest.raises(ProbeUpdateError, match="ng_measurements: 2.5"):
        ProbeSchedule(ng_measurements=2.5)
    with pytest.raises(SlowErrorError, match="noise_ratio: -1"):
        SlowErrorFilter(noise_ratio=-1)
    with pytest.raises(SlowErrorError, match="bias_time_constant_s: inf"):
        SlowErrorFilter(bias_time_constant_s=math.inf)


def test_q_prod_charges_each_probing():
    assert q_prod_pct(10, 10 * 7200.0, 95.0) == pytest.approx(100.0 * (1 - 95.0 / 7200.0))
    with pytest.raises(ProbeUpdateError, match="duration_s"):
        q_prod_pct(1, 0.0, 95.0)


def test_a_load_change_starts_a_dense_probing_phase_and_one_inside_it_is_ignored():
    t = _rows(10)
    y = np.zeros(t.size)
    change = int(3 * 3600.0 / DT)
    r = run_probe_updates(t, y, y, 1, ProbeSchedule(acl_um=math.inf), [SlowErrorFilter()],
                          load_change_rows=[change, change + 40])
    assert r.load_change_phases == 1 and r.no_good_phases == 0
    after = [k for k in r.probe_rows if k > change]
    assert t[after[0]] - t[change] == pytest.approx(600.0, abs=DT)   # first probe 10 min after the change
    assert np.all(np.diff(t[after[:12]]) < 695.0 + DT)                # 12 dense probings
    assert t[after[12]] - t[after[11]] >= 7295.0                      # then the plain schedule again
    plain = run_probe_updates(t, y, y, 1, ProbeSchedule(acl_um=math.inf), [SlowErrorFilter()])
    assert len(plain.probe_rows) < len(r.probe_rows)
