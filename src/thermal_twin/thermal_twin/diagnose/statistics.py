"""Residual statistics of the mismatch finder: whiteness, cross-correlation, spectrum, drift.

Pure numpy/scipy/statsmodels; every function takes plain arrays.

- :func:`ljung_box`: is a residual white (Ljung-Box Q over a set of lags, statsmodels)?
- :func:`derived_drivers`: candidate drivers from a recording's inputs and sensors: each
  input, speed and speed^2 of speed-like inputs, recorded power, temperature rates dT/dt.
- :func:`cross_correlation`: residual vs. driver over lags after prewhitening the driver
  (Box-Jenkins), with a pointwise 95 % band from Bartlett's formula (without prewhitening,
  slow thermal signals correlate with everything) and a simultaneous band over all lags
  (Sidak) that decides significance.
- :func:`spectral_peaks`: periodogram peaks of a residual; a period near 24 h points to ambient.
- :func:`drift`: linear trend with Newey-West (HAC) standard errors.
- :func:`channel_sigma`, :func:`quantisation_step`, :func:`recorded_resolution`: a channel's
  measurement noise and the lattice its readings lie on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np
import scipy.signal
import scipy.stats
import statsmodels.api as sm
from statsmodels.tsa.stattools import acf

DAY_S = 86400.0


def fill_gaps(x: np.ndarray) -> np.ndarray:
    """x with NaNs (failed readings) replaced by linear interpolation (edges: nearest)."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    if ok.all():
        return x
    if not ok.any():
        raise ValueError("series has no finite value")
    idx = np.arange(x.size)
    return np.interp(idx, idx[ok], x[ok])


def ljung_box(residual: np.ndarray, lags: int = 20, alpha: float = 0.01) -> dict:
    """Ljung-Box test of whiteness at ``lags`` lags.

    Returns ``{"q": Q, "p_value": p, "lags": lags, "white": p >= alpha}``.
    """
    r = fill_gaps(residual)
    lags = int(max(1, min(lags, r.size // 4)))
    if np.std(r) == 0.0:
        return {"q": 0.0, "p_value": 1.0, "lags": lags, "white": True}
    # the Ljung-Box Q of statsmodels' acf (FFT); acorr_ljungbox computes the same statistic
    # with a direct O(n^2) autocorrelation, too slow for day-long recordings at 15 s
    _, qs, ps = acf(r - r.mean(), nlags=lags, fft=True, qstat=True, result_object=False)
    q, p = float(qs[-1]), float(ps[-1])
    return {"q": q, "p_value": p, "lags": lags, "white": bool(p >= alpha)}


def is_speed_like(name: str) -> bool:
    n = name.lower()
    return "rpm" in n or "speed" in n


def is_power_like(name: str) -> bool:
    n = name.lower()
    return "power" in n or n.endswith("_w") or n.endswith("_kw")


def temperature_rate(time_s: np.ndarray, temp: np.ndarray, smooth_s: float = 900.0) -> np.ndarray:
    """dT/dt in K/h, after a centred moving average over ``smooth_s`` (sensor noise and
    quantisation would otherwise dominate the derivative)."""
    t = np.asarray(time_s, dtype=float)
    y = fill_gaps(temp)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    w = int(max(1, round(smooth_s / dt)))
    if w > 1 and y.size > w:
        kernel = np.ones(w) / w
        pad = np.pad(y, (w // 2, w - 1 - w // 2), mode="edge")
        y = np.convolve(pad, kernel, mode="valid")
    return np.gradient(y, t) * 3600.0


def derived_drivers(time_s: np.ndarray, inputs: dict[str, np.ndarray],
                    sensors: dict[str, np.ndarray], sensor_levels: bool = False) -> dict[str, np.ndarray]:
    """Candidate drivers: every input; ``speed`` and ``speed^2`` for speed-like inputs
    (normalised to their maximum, so they are unit-free); power-like inputs as they are;
    the rate ``d(sensor)/dt`` of every sensor; with ``sensor_levels`` also every sensor
    level (useful for temperatures the twin does not model; for modelled ones the
    residual correlates with the reading by construction)."""
    out: dict[str, np.ndarray] = {}
    for name, u in inputs.items():
        u = fill_gaps(u)
        out[name] = u
        if is_speed_like(name):
            scale = float(np.max(np.abs(u))) or 1.0
            out[f"{name}^2"] = (u / scale) ** 2
    for name, y in sensors.items():
        try:
            if sensor_levels:
                out[name] = fill_gaps(y)
            out[f"d({name})/dt"] = temperature_rate(time_s, y)
        except ValueError:
            continue
    return out


def _acf(x: np.ndarray, nlags: int) -> np.ndarray:
    x = x - x.mean()
    n = x.size
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: nlags + 1]
    return ac / ac[0] if ac[0] > 0 else np.zeros(nlags + 1)


@dataclass
class CrossCorrelation:
    driver: str
    lags: np.ndarray          # in samples; positive lag k: residual follows the driver by k
    ccf: np.ndarray           # correlation of residual(t) with driver(t - k)
    band: float               # half-width of the pointwise 95 % band (Bartlett)
    peak_lag: int
    peak_value: float

    @property
    def simultaneous_band(self) -> float:
        """The band for the largest of all lags (Sidak: 5 % over the 2L+1 lags looked at);
        the pointwise band would be crossed by chance somewhere among many lags."""
        m = max(1, self.lags.size)
        z = float(scipy.stats.norm.ppf(1.0 - (1.0 - 0.95 ** (1.0 / m)) / 2.0))
        return self.band * z / 1.959963984540054

    @property
    def significant(self) -> bool:
        return abs(self.peak_value) > self.simultaneous_band

    def as_dict(self, dt_s: float) -> dict:
        return {"driver": self.driver, "peak_lag_s": float(self.peak_lag * dt_s),
                "peak_ccf": float(self.peak_value), "band_95": float(self.band),
                "band_95_all_lags": float(self.simultaneous_band),
                "significant": bool(self.significant)}


def _ar_prewhitener(u: np.ndarray, order: int) -> np.ndarray:
    """Coefficients a (length order+1, a[0] = 1) of the AR filter that whitens u."""
    p = int(max(1, min(order, u.size // 10)))
    X = np.column_stack([u[p - k - 1: u.size - k - 1] for k in range(p)])
    coef, *_ = np.linalg.lstsq(X, u[p:], rcond=None)
    return np.concatenate([[1.0], -coef])


def cross_correlation(residual: np.ndarray, driver: np.ndarray, max_lag: int,
                      name: str = "", ar_order: int = 8) -> CrossCorrelation:
    """Cross-correlation r_eu(k) = corr(e(t), u(t-k)) for k = -max_lag..max_lag after
    prewhitening (Box-Jenkins): an AR model fitted to the driver whitens it, and the same
    filter is applied to the residual, so r_eu(k) estimates the (scaled) impulse response
    of the unmodelled path from u to e and a peak at lag k means the path from u(t-k) is
    mis-modelled. The 95 % band uses Bartlett's variance (1/N) sum_k r_ee(k) r_uu(k) of the
    filtered series, which reduces to 1.96/sqrt(N) once the driver is white.
    """
    e = scipy.signal.detrend(fill_gaps(residual))
    u = scipy.signal.detrend(fill_gaps(driver))
    n = e.size
    max_lag = int(max(0, min(max_lag, n // 3)))
    lags = np.arange(-max_lag, max_lag + 1)
    if e.std() == 0 or u.std() == 0:
        return CrossCorrelation(name, lags, np.zeros(lags.size), 1.0, 0, 0.0)
    a = _ar_prewhitener(u / u.std(), ar_order)
    u = scipy.signal.lfilter(a, [1.0], u)[a.size:]
    e = scipy.signal.lfilter(a, [1.0], e)[a.size:]
    n = e.size
    se, su = e.std(), u.std()
    if se == 0 or su == 0:
        return CrossCorrelation(name, lags, np.zeros(lags.size), 1.0, 0, 0.0)
    full = scipy.signal.correlate(e - e.mean(), u - u.mean(), mode="full", method="fft") / (n * se * su)
    mid = n - 1
    ccf = full[mid - max_lag: mid + max_lag + 1]
    m = int(min(n - 1, max(max_lag, 50) * 2))
    ree, ruu = _acf(e, m), _acf(u, m)
    var = (1.0 + 2.0 * float(np.sum(ree[1:] * ruu[1:]))) / n
    band = 1.96 * math.sqrt(max(var, 1.0 / n))
    i = int(np.argmax(np.abs(ccf)))
    return CrossCorrelation(name, lags, ccf, band, int(lags[i]), float(ccf[i]))


def spectral_peaks(residual: np.ndarray, dt_s: float, n_peaks: int = 3,
                   min_period_s: float = 1800.0) -> list[dict]:
    """The strongest periodogram peaks (linear trend removed, Hann window) with period in
    hours and share of the residual's variance; a period within 20 % of 24 h is labelled
    ``ambient (daily)``. Periods longer than 2/3 of the record are not resolvable and skipped."""
    e = fill_gaps(residual)
    n = e.size
    if n < 16:
        return []
    f, p = scipy.signal.periodogram(e, fs=1.0 / dt_s, window="hann", detrend="linear")
    total = float(np.sum(p[1:])) or 1.0
    keep = (f > 0) & (f >= 1.5 / (n * dt_s)) & (f <= 1.0 / min_period_s)
    if not keep.any():
        return []
    idx = np.flatnonzero(keep)
    pk, _ = scipy.signal.find_peaks(np.concatenate([[0.0], p[idx], [0.0]]))
    pk = pk - 1  # the zero padding lets the first and last resolvable bins be peaks
    cand = idx[pk] if pk.size else idx[[int(np.argmax(p[idx]))]]
    cand = cand[np.argsort(p[cand])[::-1]][:n_peaks]
    out = []
    for i in cand:
        period_h = 1.0 / f[i] / 3600.0
        share = float(np.sum(p[max(i - 1, 1): i + 2]) / total)
        label = "ambient (daily)" if abs(period_h - 24.0) <= 4.8 else ""
        out.append({"period_h": float(period_h), "power_share": share, "label": label})
    return out


def drift(time_s: np.ndarray, residual: np.ndarray, maxlags: int | None = None) -> dict:
    """Linear trend of the residual per hour with a Newey-West 95 % interval; the
    trend counts as drift when the interval excludes zero."""
    t = np.asarray(time_s, dtype=float) / 3600.0
    e = fill_gaps(residual)
    if e.size < 8 or np.std(e) == 0:
        return {"slope_per_h": 0.0, "ci95": [0.0, 0.0], "significant": False}
    X = sm.add_constant(t - t.mean())
    lag = int(maxlags if maxlags is not None else min(e.size // 4, max(1, int(4 * (e.size / 100) ** (2 / 9)) * 10)))
    fit = sm.OLS(e, X).fit(cov_type="HAC", cov_kwds={"maxlags": lag})
    slope = float(fit.params[1])
    lo, hi = (float(v) for v in fit.conf_int(alpha=0.05)[1])
    return {"slope_per_h": slope, "ci95": [lo, hi], "significant": bool(lo > 0 or hi < 0)}


def channel_sigma(x: np.ndarray) -> float:
    """Measurement noise of a channel from its second differences (var = 6 sigma^2 for
    white noise; smooth thermal transients nearly cancel): the MAD estimate (robust to the
    kinks of steps), but at least a quarter of the plain std estimate (a quantised, slowly
    varying reading has a zero MAD), floored at 1e-3."""
    x = np.asarray(x, dtype=float)
    d = np.diff(x[np.isfinite(x)], n=2)
    if d.size < 2:
        return 1.0
    s_mad = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(6.0)
    s_std = float(np.std(d)) / math.sqrt(6.0)
    return max(s_mad, 0.25 * s_std, 1e-3)


def quantisation_step(x: np.ndarray) -> float:
    """The step of the lattice a channel's readings lie on (0.0 when they lie on none): the
    smallest change between consecutive readings, if every reading is the first plus an
    integer number of it. A reading quantised much more coarsely than its noise is a
    staircase whose second differences are mostly zero, so :func:`channel_sigma` sees almost
    no noise while the reading errs by up to half a step; the step says how much."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 3:
        return 0.0
    d = np.abs(np.diff(x))
    tiny = 1e-9 * max(1.0, float(np.max(np.abs(x))))
    d = d[d > tiny]
    if d.size == 0:
        return 0.0
    q = float(np.min(d))
    k = (x - x[0]) / q
    return q if float(np.max(np.abs(k - np.rint(k)))) < 1e-3 else 0.0


def recorded_resolution(sensor_resolution: Mapping[str, float], columns: Mapping[str, np.ndarray],
                        channels: Iterable[str]) -> dict[str, float]:
    """The quantisation step of each column: the twin's sensor resolution (``sensor_resolution``,
    by column), raised for each of ``channels`` to the lattice its recorded readings lie on (a
    recorder may quantise more coarsely than the twin's sensors)."""
    res = dict(sensor_resolution)
    for c in channels:
        res[c] = max(res.get(c, 0.0), quantisation_step(columns[c]))
    return res
