"""A channel's noise as white readings plus a wandering level, fitted by maximum likelihood.

The model of one channel's residual r_t (reading minus twin, in units of its white part):

    r_t = l_t + w_t,   w_t ~ N(0, s^2),   l_{t+1} = phi l_t + eta_t,   eta_t ~ N(0, ratio s^2):

phi = 1 is a random walk (local level), phi < 1 an AR(1) level, ratio = 0 white readings. A
Kalman filter gives the one-step innovations v_t (reading minus its prediction from every
earlier reading) and their variances F_t s^2; the log-likelihood with s^2 profiled out is
-(n log(sum v^2/F / n) + sum log F) / 2.

:func:`fit_level_noise` fits (phi, ratio) per channel on a grid by that likelihood, the level
being a free constant (diffuse prior) plus the wandering part, so a constant offset of the
residual (one a fitted bias removed) does not change the fit; the white model is kept unless
the level is significant (likelihood ratio against a constant plus white readings,
:data:`LEVEL_ALPHA`, two parameters).

:func:`whiten` gives a residual's standardised innovations v_t / sqrt(F_t) on a window of
rows judged on its own: the level's prior at the window's first row is its unconditional
variance there (zero at row 0, where the twin starts from the recorded state), so the sum of
squares is the generalised-least-squares form r' Sigma^-1 r of the window under the fitted
covariance. A walk that drifted 1-2 sigma by the held-out window is within its own spread
there, and within the window each reading is predicted by the walk's recent level: a bias or a
slow gain that only follows the walk gains little, a bias far beyond the walk's spread or a
change the walk cannot follow (a step, a response to an input) still does. A white channel's
innovations are its residual, bit for bit.

:func:`judged_sums` is the one place both are used: a change judged by its held-out
innovations under the noise of :func:`change_noise`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

#: level persistence per step of the fitted series: AR(1) levels of short to long memory, and the walk
PHIS = (0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 1.0)
#: level innovation variance over the white variance, per step of the fitted series
RATIOS = tuple(float(v) for v in np.geomspace(1e-5, 30.0, 14))
#: the white model is kept unless the level's likelihood ratio is significant at this level
LEVEL_ALPHA = 0.01
#: the likelihood is evaluated on at most this many samples (every k-th of a longer series)
MAX_FIT_SAMPLES = 1500
#: prior variance of a diffuse level (white-noise units): far above any residual's
DIFFUSE = 1e8


@dataclass(frozen=True)
class LevelNoise:
    """Fitted level of each channel, per sample of the full-resolution series: ``phi`` and
    ``ratio`` arrays (channels,), ratio 0 where the channel is white."""

    phi: np.ndarray
    ratio: np.ndarray

    @property
    def white(self) -> np.ndarray:
        return self.ratio <= 0.0

    @staticmethod
    def all_white(n_channels: int) -> "LevelNoise":
        return LevelNoise(np.ones(n_channels), np.zeros(n_channels))

    def as_dict(self, channels: list[str]) -> dict:
        return {c: {"phi": float(p), "ratio": float(q)} for c, p, q in zip(channels, self.phi, self.ratio)
                if q > 0}


def start_variance(phi: np.ndarray, ratio: np.ndarray, t0: int) -> np.ndarray:
    """Variance of the level at row ``t0`` (in white-noise units), the level being zero before
    row 0: ratio * sum_{j<=t0} phi^(2j); t0 + 1 steps of a walk, an AR(1) level's stationary
    variance once t0 is long against its memory."""
    phi = np.asarray(phi, dtype=float)
    ratio = np.asarray(ratio, dtype=float)
    p2 = phi ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        geo = np.where(p2 < 1.0, (1.0 - p2 ** (t0 + 1)) / (1.0 - p2), float(t0 + 1))
    return ratio * geo


def _filter(r: np.ndarray, valid: np.ndarray, phi: np.ndarray, ratio: np.ndarray, p0: np.ndarray,
            keep: bool, mean_var: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Kalman filter of rows ``r`` (channels, n) with the level parameters broadcast against
    (channels, G); the level is c + a, a the AR(1) or walk part started with variance ``p0``, c a
    constant of prior variance ``mean_var`` (0: none; large: the fit ignores a constant offset).
    Missing readings (``valid`` False) are not observed. Returns (sum of v^2/F, sum of log F
    over the observed readings, the standardised innovations (channels, G, n) when ``keep``)."""
    shape = (r.shape[0], np.broadcast(phi, ratio, p0).shape[-1])
    c, a = np.zeros(shape), np.zeros(shape)
    pcc, pca = np.full(shape, float(mean_var)), np.zeros(shape)
    paa = np.broadcast_to(p0, shape).astype(float)
    ssq, logf = np.zeros(shape), np.zeros(shape)
    e = np.zeros(shape + (r.shape[1],)) if keep else None
    for t in range(r.shape[1]):
        ok = valid[:, t][:, None]
        hc, ha = pcc + pca, pca + paa           # covariance of (c, a) with the level c + a
        F = hc + ha + 1.0
        v = r[:, t][:, None] - c - a
        z = np.where(ok, v / np.sqrt(F), 0.0)
        ssq += z * z
        logf += np.where(ok, np.log(F), 0.0)
        if keep:
            e[..., t] = z
        g = np.where(ok, 1.0 / F, 0.0)
        c, a = c + hc * g * v, a + ha * g * v
        pcc, pca, paa = pcc - hc * hc * g, pca - hc * ha * g, paa - ha * ha * g
        a, pca, paa = phi * a, phi * pca, phi * phi * paa + ratio
    return ssq, logf, e


def _profile_loglik(ssq: np.ndarray, logf: np.ndarray, n: np.ndarray) -> np.ndarray:
    n = np.maximum(n, 1)
    return -0.5 * (n * np.log(np.maximum(ssq, 1e-300) / n) + logf)


def fit_level_noise(r: np.ndarray, valid: np.ndarray, stride: int = 1) -> LevelNoise:
    """Maximum-likelihood level of each row of ``r`` (channels, n; a residual sampled every
    ``stride`` rows of the recording, from row 0), the white model kept unless rejected by the
    likelihood-ratio test; the result is per row of the recording."""
    r = np.atleast_2d(np.asarray(r, dtype=float))
    valid = np.atleast_2d(np.asarray(valid, dtype=bool))
    k = max(1, int(math.ceil(r.shape[1] / MAX_FIT_SAMPLES)))
    r, valid = np.where(valid, r, 0.0)[:, ::k], valid[:, ::k]
    step = max(1, int(stride)) * k
    n = valid.sum(axis=1)[:, None].astype(float)
    phis = np.repeat(np.asarray(PHIS, dtype=float), len(RATIOS))[None, :]
    ratios = np.tile(np.asarray(RATIOS, dtype=float), len(PHIS))[None, :]
    # the reference (ratio 0) is a constant level plus white readings, started diffuse too
    phis, ratios = np.concatenate([[[1.0]], phis], axis=1), np.concatenate([[[0.0]], ratios], axis=1)
    ssq, logf, _ = _filter(r, valid, phis, ratios, start_variance(phis, ratios, 0), False, DIFFUSE)
    ll_all = _profile_loglik(ssq, logf, n)
    ll, ll_white = ll_all[:, 1:], ll_all[:, 0]
    phis, ratios = phis[:, 1:], ratios[:, 1:]
    best = np.argmax(ll, axis=1)
    rows = np.arange(r.shape[0])
    level = 2.0 * (ll[rows, best] - ll_white) > scipy.stats.chi2.isf(LEVEL_ALPHA, 2)
    phi_s, ratio_s = phis[0, best], ratios[0, best]
    # per row of the recording: phi^step = phi_s, and the level's variance over step rows the same
    phi_f = phi_s ** (1.0 / step)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(phi_s < 1.0, (1.0 - phi_f ** 2) / (1.0 - phi_s ** 2), 1.0 / step)
    return LevelNoise(np.where(level, phi_f, 1.0), np.where(level, ratio_s * scale, 0.0))


def whiten(r: np.ndarray, valid: np.ndarray, noise: LevelNoise, start: int = 0) -> np.ndarray:
    """Standardised one-step innovations on rows ``start`` .. of ``r`` (channels, n: every row of
    the recording from its first) under ``noise``: the window judged on its own, the level's
    prior at ``start`` its unconditional variance there (:func:`start_variance`, the level zero
    at row 0: the twin starts from the recorded state); missing readings give 0. White channels
    are returned as they are."""
    r = np.atleast_2d(np.asarray(r, dtype=float))[:, start:]
    valid = np.atleast_2d(np.asarray(valid, dtype=bool))[:, start:]
    out = np.where(valid, r, 0.0)
    lv = np.flatnonzero(~noise.white)
    if lv.size == 0 or r.shape[1] == 0:
        return out
    phi, ratio = noise.phi[lv][:, None], noise.ratio[lv][:, None]
    _, _, e = _filter(out[lv], valid[lv], phi, ratio, start_variance(phi, ratio, start), keep=True)
    out[lv] = e[:, 0, :]
    return out


def change_noise(before: LevelNoise, after: LevelNoise) -> LevelNoise:
    """The noise a change is judged by, per channel: white where the residual after the change
    is white (the change explains the channel's structure: judged as white readings), else the
    level of the residual before it (a fit on the training window cannot have shaped that one;
    a fit that follows part of a walk leaves a residual that looks mean-reverting)."""
    white = after.white
    return LevelNoise(np.where(white, 1.0, before.phi), np.where(white, 0.0, before.ratio))


def judged_sums(fit_before: np.ndarray, fit_after: np.ndarray, fit_valid: np.ndarray, stride: int,
                residuals: list[np.ndarray], valid: np.ndarray, start: int) -> tuple[list[float], np.ndarray, LevelNoise]:
    """Under the noise of a change (:func:`change_noise`, fitted on the training residuals
    before and after it, every ``stride`` rows), the sum of squared innovations on rows
    ``start`` .. of each of ``residuals`` (every row of the recording, one covariance for all,
    so their differences are likelihood ratios); returns (the sums, the innovations of the last
    residual, the noise)."""
    noise = change_noise(fit_level_noise(fit_before, fit_valid, stride), fit_level_noise(fit_after, fit_valid, stride))
    ws = [whiten(r, valid, noise, start) for r in residuals]
    return [float(np.sum(w ** 2)) for w in ws], ws[-1], noise
