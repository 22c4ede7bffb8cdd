"""Out-of-vocabulary physics: a sparse discrepancy term, reported as ``unnamed``.

When no word of the effect vocabulary explains a structured residual, each channel's
residual is regressed on a library of candidate signals built from the recording alone
(inputs normalised to their maximum, their squares and low-passed forms; every recorded
temperature relative to its start, squared, low-passed and differentiated; products of
inputs and temperatures; time). Terms are chosen by stability selection (Meinshausen and
Buehlmann): a Lasso at the cross-validated penalty on many half-samples of contiguous
blocks of the training window, keeping the terms selected in at least ``THRESHOLD`` of
them; the kept terms are refitted by least squares. A channel's term counts only if it
improves the held-out window over a constant offset with a held-out F test that survives
Holm's correction over the channels tried. The result names a formula, its held-out
improvement and the nearest vocabulary word, and is never labelled with that word.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from thermal_comp_common.runtime.task_engine import map_tasks
from thermal_twin.diagnose import statistics as stats
from thermal_twin.diagnose.fit import effective_samples
from thermal_twin.diagnose.significance import holdout_p_value, holm_reject

THRESHOLD = 0.8              # selection frequency a term needs
N_SUBSAMPLES = 40
LOWPASS_S = (3600.0, 4 * 3600.0)
MAX_TERMS = 3                # a discrepancy is a few terms, not a black box


@dataclass
class Term:
    name: str
    kind: str                 # time, input, input^2, lowpass_input, temp, temp^2, lowpass_temp, rate, product
    signal: np.ndarray


def _lowpass(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    a = float(np.exp(-dt / tau))
    y = np.empty_like(x)
    acc = x[0]
    for k, v in enumerate(x):        # first-order lag, the same as a sensor lag
        acc = a * acc + (1.0 - a) * v
        y[k] = acc
    return y


def signal_library(time_s: np.ndarray, inputs: dict[str, np.ndarray],
                   sensors: dict[str, np.ndarray]) -> list[Term]:
    """The candidate signals of the discrepancy (see the module docstring)."""
    t = np.asarray(time_s, dtype=float)
    dt = float(np.median(np.diff(t)))
    lib = [Term("t_h", "time", (t - t[0]) / 3600.0)]
    norm_inputs = {}
    for name, u in inputs.items():
        u = stats.fill_gaps(u)
        if np.ptp(u) <= 0:
            continue
        un = u / (float(np.max(np.abs(u))) or 1.0)
        norm_inputs[name] = un
        lib += [Term(f"{name}/max", "input", un), Term(f"({name}/max)^2", "input^2", un ** 2)]
        lib += [Term(f"lowpass_{tau / 3600:g}h({name}/max)", "lowpass_input", _lowpass(un, dt, tau))
                for tau in LOWPASS_S]
    for name, y in sensors.items():
        try:
            y = stats.fill_gaps(y)
        except ValueError:
            continue
        if np.ptp(y) <= 0:
            continue
        d = y - y[0]
        lib += [Term(f"d{name}", "temp", d), Term(f"d{name}^2", "temp^2", d ** 2),
                Term(f"d({name})/dt", "rate", stats.temperature_rate(t, y))]
        lib += [Term(f"lowpass_{tau / 3600:g}h(d{name})", "lowpass_temp", _lowpass(d, dt, tau)) for tau in LOWPASS_S]
        lib += [Term(f"{u}/max*d{name}", "product", un * d) for u, un in norm_inputs.items()]
    return lib


NEAREST = {"time": "sensor_bias", "input": "heat_source", "input^2": "heat_source",
           "lowpass_input": "heat_source", "lowpass_temp": "time_lag", "rate": "time_lag",
           "product": "speed_dependent_convection"}


def nearest_word(term: Term, channel_is_error: bool) -> str:
    if term.kind in NEAREST:
        return NEAREST[term.kind]
    return "elastic_gain" if channel_is_error else "ambient_coupling"


def _stability(X: np.ndarray, y: np.ndarray, rng: np.random.Generator, n_blocks: int = 20) -> np.ndarray:
    """Selection frequency of every column over half-samples of contiguous blocks."""
    # heavy: scikit-learn only when fitting
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import Lasso, LassoCV
    from sklearn.model_selection import TimeSeriesSplit
    blocks = np.array_split(np.arange(y.size), n_blocks)
    freq = np.zeros(X.shape[1])
    with warnings.catch_warnings():
        # strongly collinear slow signals: the last digits of a Lasso path do not matter here
        warnings.simplefilter("ignore", ConvergenceWarning)
        alpha = LassoCV(cv=TimeSeriesSplit(5), alphas=30, max_iter=3000, tol=1e-3).fit(X, y).alpha_
        for _ in range(N_SUBSAMPLES):
            pick = rng.choice(n_blocks, n_blocks // 2, replace=False)
            idx = np.concatenate([blocks[i] for i in sorted(pick)])
            coef = Lasso(alpha=alpha, max_iter=3000, tol=1e-3, precompute=True).fit(X[idx], y[idx]).coef_
            freq += np.abs(coef) > 1e-10
    return freq / N_SUBSAMPLES


@dataclass
class Discrepancy:
    channel: str
    terms: list[str]
    coefficients: list[float]
    offset: float
    selection_frequency: list[float]
    nearest: str
    sse_holdout_before: float
    sse_holdout_after: float
    p_value: float
    prediction: np.ndarray          # the formula as printed (offset and terms), channel units
    holm_pass: bool = False

    @property
    def holdout_improvement_pct(self) -> float:
        return 100.0 * (1.0 - self.sse_holdout_after / max(self.sse_holdout_before, 1e-300))

    def formula(self, unit: str) -> str:
        parts = [f"{self.offset:+.4g}"] + [f"{c:+.4g}*{n}" for c, n in zip(self.coefficients, self.terms)]
        return f"{self.channel} += {' '.join(parts)} [{unit}]"

    def as_dict(self, unit: str) -> dict:
        return {"effect": "unnamed", "channel": self.channel, "formula": self.formula(unit),
                "terms": [{"signal": n, "coefficient": c, "selection_frequency": f}
                          for n, c, f in zip(self.terms, self.coefficients, self.selection_frequency)],
                "offset": self.offset, "nearest_vocabulary_word": self.nearest,
                "holdout_improvement_pct": self.holdout_improvement_pct, "p_value": self.p_value,
                "holm_pass": self.holm_pass}


def fit_channel(channel: str, resid: np.ndarray, lib: list[Term], n_train: int, is_error: bool,
                seed: int = 0) -> Discrepancy | None:
    """Stability-selected sparse discrepancy of one channel's residual (None: no term)."""
    r = stats.fill_gaps(resid)
    ok = np.isfinite(np.asarray(resid, dtype=float))
    stride = max(1, n_train // 1500)
    tr = np.arange(0, n_train, stride)
    tr = tr[ok[tr]]
    X_all = np.column_stack([term.signal for term in lib])
    mu, sd = X_all[tr].mean(axis=0), X_all[tr].std(axis=0)
    # a reading's own forms carry its noise, which the residual shares: never a regressor
    own = np.array([(not is_error) and channel in term.name for term in lib])
    usable = (sd > 1e-12) & ~own
    Z = np.where(usable, (X_all - mu) / np.where(usable, sd, 1.0), 0.0)
    y = r[tr] - r[tr].mean()
    if np.std(y) <= 0:
        return None
    freq = _stability(Z[tr], y / np.std(y), np.random.default_rng(seed))
    order = [j for j in np.argsort(-freq) if freq[j] >= THRESHOLD and usable[j]][:MAX_TERMS]
    if not order:
        return None
    A = np.column_stack([np.ones(tr.size)] + [X_all[tr, j] for j in order])
    coef, *_ = np.linalg.lstsq(A, r[tr], rcond=None)
    full = np.column_stack([np.ones(r.size)] + [X_all[:, j] for j in order]) @ coef
    ho = np.arange(n_train, r.size)
    ho = ho[ok[ho]]
    # the terms must beat a constant offset (a bias is vocabulary) and the twin as it is
    base = r[ho] - r[:n_train][ok[:n_train]].mean()
    after = r[ho] - full[ho]
    s0, s1 = min(float(base @ base), float(r[ho] @ r[ho])), float(after @ after)
    p = holdout_p_value(s0, s1, len(order), effective_samples(after[None, :]))
    lead = max(order, key=lambda j: abs(coef[1 + order.index(j)]) * sd[j])
    return Discrepancy(channel, [lib[j].name for j in order], [float(c) for c in coef[1:]], float(coef[0]),
                       [float(freq[j]) for j in order], nearest_word(lib[lead], is_error), s0, s1, p, full)


def _channel_task(shared: tuple, channel: str) -> Discrepancy | None:
    residuals, lib, n_train, errors = shared
    return fit_channel(channel, residuals[channel], lib, n_train, channel in errors)


def find_unnamed(residuals: dict[str, np.ndarray], lib: list[Term], n_train: int, errors: set[str],
                 min_improvement_pct: float = 5.0, engine=None) -> list[Discrepancy]:
    """Discrepancies of the channels whose held-out improvement passes Holm over the
    channels tried and ``min_improvement_pct``; best first. The channels are tasks of
    :func:`thermal_comp_common.runtime.task_engine.map_tasks` on ``engine`` (default serial)."""
    fits: list = [None] * len(residuals)
    for i, d in map_tasks(_channel_task, (residuals, lib, n_train, errors), list(residuals), engine):
        fits[i] = d
    found = [d for d in fits if d is not None]
    for d, ok in zip(found, holm_reject([d.p_value for d in found], len(residuals))):
        d.holm_pass = ok
    good = [d for d in found if d.holm_pass and d.holdout_improvement_pct >= min_improvement_pct]
    return sorted(good, key=lambda d: -d.holdout_improvement_pct)
