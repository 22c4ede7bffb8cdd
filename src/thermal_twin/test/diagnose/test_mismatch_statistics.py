"""Residual statistics and locating: whiteness, prewhitened cross-correlation, spectrum, drift, windows."""
from __future__ import annotations

import numpy as np
import scipy.signal
from statsmodels.stats.diagnostic import acorr_ljungbox

from thermal_twin.diagnose import locate
from thermal_twin.diagnose import statistics as stats
DT = 60.0


def _ar1(n, phi, rng):
    return scipy.signal.lfilter([1.0], [1.0, -phi], rng.standard_normal(n))


def test_ljung_box_separates_white_from_autocorrelated_and_matches_statsmodels():
    rng = np.random.default_rng(0)
    white = rng.standard_normal(600)
    assert stats.ljung_box(white)["white"]
    assert not stats.ljung_box(_ar1(600, 0.8, rng))["white"]
    ref = acorr_ljungbox(white - white.mean(), lags=[20], return_df=True)
    lb = stats.ljung_box(white, lags=20)
    assert np.isclose(lb["q"], float(ref["lb_stat"].iloc[0]), rtol=1e-9)
    assert np.isclose(lb["p_value"], float(ref["lb_pvalue"].iloc[0]), rtol=1e-9)


def test_cross_correlation_finds_the_lag_of_a_missing_path():
    rng = np.random.default_rng(1)
    n = 3000
    u = np.repeat(rng.choice([0.0, 1.0, 2.0], n // 30 + 1), 30)[:n] + 0.05 * rng.standard_normal(n)
    lag = 12
    e = np.concatenate([np.zeros(lag), u[:-lag]]) * 0.5 + 0.3 * rng.standard_normal(n)
    cc = stats.cross_correlation(e, u, max_lag=60, name="u")
    assert cc.significant
    assert cc.peak_lag == lag
    assert cc.as_dict(DT)["peak_lag_s"] == lag * DT


def test_cross_correlation_band_holds_its_false_alarm_rate_for_independent_slow_series():
    """Two independent random walks correlate strongly at face value; after prewhitening
    the 95 % band must flag about 5 % of such pairs, not most of them."""
    flagged = 0
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        e = np.cumsum(rng.standard_normal(1500))
        u = np.cumsum(rng.standard_normal(1500))
        cc = stats.cross_correlation(e, u, max_lag=0)
        flagged += cc.significant
    assert flagged <= 6, f"{flagged}/40 independent pairs flagged"


def test_largest_of_many_lags_is_judged_against_the_simultaneous_band():
    """Over 2*60+1 lags the pointwise band is crossed somewhere most of the time; the
    decision uses the band for all lags, so white noise is rarely called significant."""
    crossed_pointwise = flagged = 0
    for seed in range(40):
        rng = np.random.default_rng(300 + seed)
        cc = stats.cross_correlation(rng.standard_normal(1000), rng.standard_normal(1000), max_lag=60)
        crossed_pointwise += abs(cc.peak_value) > cc.band
        flagged += cc.significant
    assert crossed_pointwise >= 20
    assert flagged <= 6, f"{flagged}/40"


def test_spectral_peak_at_24h_is_labelled_ambient():
    rng = np.random.default_rng(2)
    t = np.arange(0, 72 * 3600, DT)
    r = 0.4 * np.sin(2 * np.pi * t / 86400.0) + 0.05 * rng.standard_normal(t.size)
    peaks = stats.spectral_peaks(r, DT)
    assert abs(peaks[0]["period_h"] - 24.0) < 1.0
    assert peaks[0]["label"] == "ambient (daily)"
    assert peaks[0]["power_share"] > 0.5


def test_drift_is_found_when_present_and_rarely_in_autocorrelated_noise():
    t = np.arange(0, 48 * 3600, DT)
    rng = np.random.default_rng(3)
    d = stats.drift(t, 0.1 * _ar1(t.size, 0.9, rng) + 0.01 * t / 3600.0)
    assert d["significant"] and abs(d["slope_per_h"] - 0.01) < 0.003
    # the HAC interval keeps the false-alarm rate near 5 % (OLS errors would flag most)
    false_alarms = sum(stats.drift(t, 0.1 * _ar1(t.size, 0.9, np.random.default_rng(s)))["significant"]
                       for s in range(200, 240))
    assert false_alarms <= 6, f"{false_alarms}/40"


def test_derived_drivers_include_speed_squared_and_temperature_rates():
    t = np.arange(0, 3600 * 4, DT)
    rpm = np.where(t > 3600, 6000.0, 0.0)
    temp = 20 + 0.5 * t / 3600.0
    d = stats.derived_drivers(t, {"spindle_rpm": rpm}, {"t1_c": temp})
    assert set(d) == {"spindle_rpm", "spindle_rpm^2", "d(t1_c)/dt"}
    assert np.isclose(d["spindle_rpm^2"].max(), 1.0)
    assert np.allclose(d["d(t1_c)/dt"][20:-20], 0.5)


def test_locate_names_window_regime_and_effect_size():
    rng = np.random.default_rng(4)
    t = np.arange(0, 24 * 3600, DT)
    door = ((t >= 10 * 3600) & (t < 13 * 3600)).astype(float)
    spindle = np.where((t >= 2 * 3600) & (t < 8 * 3600), 3000.0, 0.0)
    bump = 2.0 * door
    res = {"E_X0C": bump + 0.1 * rng.standard_normal(t.size), "t1_c": 0.02 * rng.standard_normal(t.size)}
    regimes = locate.operating_regimes(t, {"spindle_rpm": spindle, "door_open": door}, start_hour=6.0)
    wins = locate.locate_windows(t, res, regimes, {"E_X0C": "um", "t1_c": "degC"})
    assert len(wins) == 1
    w = wins[0]
    assert w["channels"] == ["E_X0C"]
    assert 9.5 * 3600 <= w["start_s"] <= 10.5 * 3600 and 12.5 * 3600 <= w["end_s"] <= 13.5 * 3600
    assert "door open" in w["regime"] and "spindle stopped" in w["regime"] and "day" in w["regime"]
    assert abs(w["effect"]["E_X0C"]["value"] - 2.0) < 0.3 and w["effect"]["E_X0C"]["unit"] == "um"
    eff = locate.regime_effects(res, regimes, {"E_X0C": "um", "t1_c": "degC"})
    top = eff[0]
    assert (top["regime"], top["channel"]) == ("door open", "E_X0C")
    assert abs(top["effect"] - 2.0) < 0.1


def test_locate_reports_nothing_for_pure_noise():
    rng = np.random.default_rng(5)
    t = np.arange(0, 24 * 3600, DT)
    res = {"E_X0C": 0.1 * rng.standard_normal(t.size)}
    regimes = locate.operating_regimes(t, {})
    assert locate.locate_windows(t, res, regimes, {"E_X0C": "um"}) == []
