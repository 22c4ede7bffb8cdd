"""Fitting and ranking the effect library against a recording.

Procedure (one round, run by :func:`thermal_twin.diagnose.search_round.run_round` on the task
engine; the finder repeats it greedily on the augmented twin):

1. **Weights.** Every shared channel is scaled by its measurement noise (robust estimate
   from the second differences, see :func:`channel_sigma`), so degC and um become
   comparable and the fit is a weighted least-squares problem.
2. **Screening.** Each candidate is simulated once at its start value; the change of the
   outputs is a sensitivity direction s, and the share of the training residual it can
   explain is the error-reduction ratio (s.r)^2 / (s.s |r|^2) (the ERR of NARX term
   selection). The best few candidates, and the best of every effect type, go on.
3. **Fit.** ``scipy.optimize.least_squares`` (trf, bounded) on the training window only
   (every ``stride``-th sample of long recordings; the simulation itself runs at full
   resolution), from the best of a few start values of the non-linear parameters.
4. **Score.** The fitted twin is simulated over the whole recording; ``holdout_improvement_pct``
   is the fall of the weighted sum of squares on the held-out window (never fitted).
   The information criterion is BIC on the training window with the effective number of
   samples n_eff = n / tau (tau: integrated autocorrelation time of the residual, see
   :func:`effective_samples`), because thermal residuals are strongly autocorrelated and
   the raw n would let any term look significant.
5. **Plausibility.** Each effect checks its fitted values against physical ranges
   (sign, time constants, energy); implausible fits are ranked last and never adopted.

A hypothesis is adopted when it is plausible, dBIC < -2 (at least "positive evidence" on
the Kass-Raftery scale, with the already conservative n_eff) and it improves the held-out
fit by at least ``min_improvement_pct``; if nothing qualifies the answer is ``none``.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.stats
from scipy.optimize import least_squares
from scipy.signal import lfilter

from thermal_twin.sim.inputs_timeline import timeline_from_recording
from thermal_twin.machine.schema import MachineSpecError, load_machine
from thermal_twin.diagnose.effects import Candidate
from thermal_twin.diagnose.significance import holdout_p_value, holm_reject
# the noise estimates live with the other residual statistics; imported here for FitProblem,
# and importable from here as before
from thermal_twin.diagnose.statistics import channel_sigma, quantisation_step  # noqa: F401
from thermal_twin.diagnose.twin_eval import expected_outputs, node_states
from thermal_comp_common.recording_csv import Recording

BIC_THRESHOLD = -2.0
#: a channel is measurably worse on held-out data when its held-out RMSE rises by more than
#: this share and by more than this many noise sigmas (both: a tiny channel's share, a noisy
#: channel's sigma alone would flag noise), and the rise is significant (WORSE_ALPHA, Holm
#: over the channels tested: the rule refuses a change if any channel is worse)
WORSE_REL = 0.02
WORSE_SIGMA = 0.25
WORSE_ALPHA = 0.05


def chance_alignment_sd(change: np.ndarray, resid: np.ndarray) -> float:
    """Standard deviation of ``change . resid`` when ``resid`` is a stationary process with
    its own sample autocovariance and ``change`` a fixed signal (Bartlett: the sum over lags
    of the change's autocorrelation sums times the residual's autocovariance, written as
    (1/n) sum_k (sum_t change_t resid_t+k)^2). Not centred: a residual's offset of unknown
    sign is part of the misfit a change can meet by chance. For white noise of sigma s it is
    s |change|; for a slow misfit it grows with the misfit's memory."""
    n = change.size
    if n == 0:
        return 0.0
    m = 1 << int(np.ceil(np.log2(2 * n)))
    xc = np.fft.irfft(np.fft.rfft(change, m) * np.conj(np.fft.rfft(resid, m)), m)
    return float(np.sqrt(np.sum(xc ** 2) / n))


def worse_channels(problem: "FitProblem", y_before: np.ndarray, y_after: np.ndarray) -> list[str]:
    """Channels whose held-out RMSE (the window no fit saw) is measurably worse with
    ``y_after`` than with ``y_before``: by :data:`WORSE_REL` and :data:`WORSE_SIGMA`, and
    significantly beyond chance, judged against the twin's own residual on that channel.
    The rise of the sum of squares is D = |d|^2 - 2 d.r0 (d the change, r0 the residual
    before it); a correct change meets the twin's own misfit r0 at some alignment by chance,
    so D counts only when it exceeds what that alignment gives with r0's own memory
    (:func:`chance_alignment_sd`, one-sided normal test, Holm over the channels): on a
    simulated machine r0 is sensor noise and this is the noise test, on a real one a slow
    structured misfit the twin already had cannot by itself refuse a change. An adopted
    mechanism must not buy its improvement on some channels with a loss on another."""
    nt = problem.n_train
    n = np.maximum(problem._valid[:, nt:].sum(axis=1), 1)
    r0 = problem.weighted_residual(y_before, nt)
    r1 = problem.weighted_residual(y_after, nt)
    s0, s1 = np.sum(r0 ** 2, axis=1), np.sum(r1 ** 2, axis=1)
    b, a = np.sqrt(s0 / n), np.sqrt(s1 / n)
    cands, p = [], []
    for i, c in enumerate(problem.channels):
        if a[i] > b[i] * (1.0 + WORSE_REL) and a[i] - b[i] > WORSE_SIGMA:
            sd = 2.0 * chance_alignment_sd(r0[i] - r1[i], r0[i])
            cands.append(c)
            p.append(float(scipy.stats.norm.sf((s1[i] - s0[i]) / sd)) if sd > 0 else 0.0)
    return [c for c, ok in zip(cands, holm_reject(p, len(problem.channels), WORSE_ALPHA)) if ok]


def noise_free(spec: dict) -> dict:
    """A copy of a machine description with sensor noise and quantisation removed (for
    the twin's own ``simulate``; :meth:`FitProblem.outputs` is noise-free anyway)."""
    s = copy.deepcopy(spec)
    for d in s.get("sensors", {}).values():
        d.pop("noise_std", None)
        d.pop("resolution", None)
    return s


@dataclass
class FitProblem:
    """A recording, the channels shared with the twin, their weights and the split."""

    recording: Recording
    channels: list[str]
    n_train: int
    sigma: dict[str, float] = field(default_factory=dict)
    stride: int = 0        # fit on every stride-th training sample (0: at most ~3000 samples)
    resolution: dict[str, float] = field(default_factory=dict)   # quantisation step per channel

    def __post_init__(self):
        if self.stride <= 0:
            self.stride = max(1, self.n_train // 3000)
        if not self.sigma:
            # a quantised reading errs by up to half a step: at least the uniform
            # quantisation noise res/sqrt(12), whatever the differences suggest
            self.sigma = {c: max(channel_sigma(self.recording.columns[c]),
                                 self.resolution.get(c, 0.0) / math.sqrt(12.0))
                          for c in self.channels}
        meas = np.stack([np.asarray(self.recording.columns[c], dtype=float) for c in self.channels])
        self._valid = np.isfinite(meas)
        self._meas = np.where(self._valid, meas, 0.0)
        self._w = np.array([1.0 / self.sigma[c] for c in self.channels])[:, None]
        self.n_evals = 0

    @property
    def n(self) -> int:
        return len(self.recording)

    def outputs(self, spec: dict, stop: int | None = None) -> np.ndarray:
        """Noise-free twin outputs for the shared channels, shape (channels, time)."""
        m = load_machine(spec)
        vals = timeline_from_recording(m, self.recording).resolved(m)
        out = expected_outputs(m, self.recording.time_s, vals, stop=stop)
        self.n_evals += 1
        return np.stack([out[c] for c in self.channels])

    def weighted_residual(self, y: np.ndarray, start: int = 0, stop: int | None = None,
                          stride: int = 1) -> np.ndarray:
        """(measured - y) / sigma on [start, stop) every ``stride`` samples, NaN readings
        count as 0; shape (channels, samples)."""
        stop = y.shape[1] if stop is None else stop
        sl = slice(start, stop, stride)
        r = (self._meas[:, sl] - y[:, sl]) * self._w
        return np.where(self._valid[:, sl], r, 0.0)

    def exclude(self, mask: np.ndarray) -> None:
        """Treat the readings where ``mask`` (channels x time) is True as missing: no fit or
        score uses them."""
        self._valid &= ~np.asarray(mask, dtype=bool)
        self._meas = np.where(self._valid, self._meas, 0.0)

    def train_residual(self, y: np.ndarray) -> np.ndarray:
        """The weighted residual the fits minimise (training window, strided)."""
        return self.weighted_residual(y, 0, self.n_train, self.stride)

    def weighted(self, dy: np.ndarray) -> np.ndarray:
        return dy * self._w


@dataclass
class Hypothesis:
    candidate: Candidate
    values: np.ndarray
    spec: dict
    err_screen: float
    sse_train_before: float
    sse_train_after: float
    sse_holdout_before: float
    sse_holdout_after: float
    delta_bic: float
    reason: str | None                  # None when plausible
    change: np.ndarray = field(repr=False, default=None)   # weighted output change on train
    indistinguishable_from: list[str] = field(default_factory=list)
    round: int = 1
    n_eff_holdout: float = 0.0          # effective held-out samples of the residual after
    holm_pass: bool = True              # survives the round's Holm correction (mismatch_testing)
    worse: list[str] = field(default_factory=list)   # channels measurably worse on held-out data
    acted_improvement_pct: float | None = None        # held-out fall on the channels it acts on
    tell_apart: list[dict] = field(default_factory=list)   # per indistinguishable other: what would

    @property
    def p_value(self) -> float:
        return holdout_p_value(self.sse_holdout_before, self.sse_holdout_after, len(self.values),
                               self.n_eff_holdout)

    @property
    def plausible(self) -> bool:
        return self.reason is None

    @property
    def holdout_improvement_pct(self) -> float:
        if self.sse_holdout_before <= 0:
            return 0.0
        return 100.0 * (1.0 - self.sse_holdout_after / self.sse_holdout_before)

    @property
    def train_improvement_pct(self) -> float:
        return 100.0 * (1.0 - self.sse_train_after / max(self.sse_train_before, 1e-300))

    def supported(self, min_improvement_pct: float) -> bool:
        gain = self.holdout_improvement_pct if self.acted_improvement_pct is None else self.acted_improvement_pct
        return (self.plausible and self.delta_bic < BIC_THRESHOLD and self.holm_pass and self.holdout_improvement_pct > 0
                and gain >= min_improvement_pct)

    def rank_key(self, min_improvement_pct: float) -> tuple:
        # a fit that leaves a channel significantly worse ranks after those that do not
        return (not self.plausible, not self.supported(min_improvement_pct), bool(self.worse),
                -self.holdout_improvement_pct)

    def as_dict(self) -> dict:
        c = self.candidate
        return {"effect": c.effect, "target": c.target, "driver": c.driver,
                "params": c.param_dict(self.values),
                "score": round(self.holdout_improvement_pct, 3),
                "holdout_improvement_pct": self.holdout_improvement_pct,
                "train_improvement_pct": self.train_improvement_pct,
                "acted_channels_improvement_pct": self.acted_improvement_pct,
                "delta_bic": self.delta_bic, "screening_err": self.err_screen,
                "p_value": self.p_value, "holm_pass": self.holm_pass, "worse_channels": list(self.worse),
                "plausible": self.plausible, "reason": self.reason or "",
                "indistinguishable_from": list(self.indistinguishable_from),
                "tell_apart": [dict(w) for w in self.tell_apart], "round": self.round}


#: a channel whose held-out change is below this share of the largest channel's is not acted on
ACT_SHARE = 0.1


def acted_channels(change: np.ndarray) -> np.ndarray:
    """Mask of the channels an effect acts on: the RMS of its weighted held-out output change
    ``change`` (channels x samples) at least :data:`ACT_SHARE` of the largest channel's."""
    rms = np.sqrt(np.mean(np.asarray(change, dtype=float) ** 2, axis=1))
    top = float(rms.max()) if rms.size else 0.0
    return rms >= ACT_SHARE * top if top > 0 else np.ones(rms.size, dtype=bool)


def acted_improvement_pct(r0: np.ndarray, r1: np.ndarray) -> float:
    """Fall of the weighted held-out sum of squares, in %, on the channels the change from
    residual ``r0`` to ``r1`` acts on (a bias of one sensor among twenty channels is judged on
    its channel, not diluted by the nineteen it leaves alone)."""
    acted = acted_channels(r0 - r1)
    s0 = float(np.sum(r0[acted] ** 2))
    return 100.0 * (1.0 - float(np.sum(r1[acted] ** 2)) / s0) if s0 > 0 else 0.0


def effective_samples(r: np.ndarray) -> float:
    """Effective number of independent samples of the residual rows r (channels x time):
    n / tau with the integrated autocorrelation time tau = 1 + 2 sum_k rho(k) of the pooled
    autocorrelation, summed up to its first negative value. Unlike the AR(1) formula it
    does not change when the residual is sampled more or less densely."""
    r = np.atleast_2d(r)
    n_t = r.shape[1]
    if n_t < 4:
        return float(max(1, r.size))
    x = r - r.mean(axis=1, keepdims=True)
    f = np.fft.rfft(x, 2 * n_t, axis=1)
    c = np.fft.irfft(f * np.conj(f), axis=1)[:, :n_t].sum(axis=0)
    if c[0] <= 0:
        return float(r.size)
    rho = c[1:n_t // 2] / c[0]
    neg = np.flatnonzero(rho < 0)
    tau = 1.0 + 2.0 * float(np.sum(rho[:neg[0]] if neg.size else rho))
    return max(10.0, r.size / max(tau, 1.0))


def delta_bic(r0: np.ndarray, r1: np.ndarray, k: int) -> float:
    """BIC(after) - BIC(before) with the effective sample size of the residual before."""
    n_eff = effective_samples(r0)
    s0, s1 = float(np.sum(r0 ** 2)), float(np.sum(r1 ** 2))
    if s0 <= 0:
        return 0.0
    return n_eff * math.log(max(s1, 1e-300) / s0) + k * math.log(n_eff)


def _projection_share(S: np.ndarray, r: np.ndarray, rr: float) -> float:
    """Share of |r|^2 in the span of the columns of S (least squares, rank-safe)."""
    keep = np.linalg.norm(S, axis=0) > 0
    if not keep.any():
        return 0.0
    coef, *_ = np.linalg.lstsq(S[:, keep], r, rcond=1e-10)
    fit = S[:, keep] @ coef
    return float(fit @ fit) / rr


def screen_one(problem: FitProblem, base_spec: dict, c: Candidate, y0_train: np.ndarray,
               r0: np.ndarray, cache: dict) -> float:
    """Linearised screening of one candidate: the share of the training residual ``r0``
    (weighted, strided, raveled) that lies in the span of the candidate's output changes (the
    change at each start value of :func:`_starts`, and a finite-difference step of every further
    parameter at x0), i.e. the residual's projection on the candidate's local Jacobian (an
    error-reduction ratio that a badly placed start value of a time constant or a phase cannot
    hide). ``cache``: the base twin's node states, shared by the round's candidates
    (:func:`linear_change`)."""
    rr = float(r0 @ r0) or 1.0
    st = problem.stride
    starts, probes = probe_values(c)
    cols = []
    try:
        for v in probes:
            dy = linear_change(problem, base_spec, c, v, y0_train, cache)
            if dy is None:
                dy = problem.outputs(c.apply(base_spec, v), stop=problem.n_train) - y0_train
            cols.append(problem.weighted(dy)[:, ::st].ravel())
    except MachineSpecError:
        pass
    if not cols:
        return 0.0
    # one start's direction at a time with the steps of the further parameters, so
    # that several starts of one time constant do not add up to a flexible basis
    ns = len(starts)
    steps = cols[ns:] if len(cols) == len(probes) else []
    err = max(_projection_share(np.column_stack([d] + steps), r0, rr) for d in cols[:ns])
    return min(err, 1.0)


def probe_values(c: Candidate) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(start values, every probe): the probes are the starts (:func:`_starts`) and then a
    step of 5 % of its range in every further parameter at x0; their output changes span the
    candidate's local Jacobian that the screening projects the residual on."""
    starts = _starts(c)
    x0 = starts[0]
    probes = list(starts)
    for j in range(1, len(c.params)):
        step = x0.copy()
        p = c.params[j]
        h = 0.05 * (p.hi - p.lo)
        step[j] = x0[j] + h if x0[j] + h <= p.hi else x0[j] - h
        probes.append(step)
    return starts, probes


def linear_change(problem: FitProblem, base_spec: dict, c: Candidate, v: np.ndarray,
                  y0: np.ndarray, cache: dict) -> np.ndarray | None:
    """The output change of candidate ``c`` at ``v`` without simulating the twin, for the
    effects that act after the thermal network (None for the others): a sensor bias shifts
    its reading, an elastic gain adds gain x (node temperature - its start) to its channel,
    and a lag on a sensor without one filters the twin's reading (the reading is gain x true
    + bias, and the first-order lag started at the first value passes constants, so lagging
    the reading equals the twin's lag of the true temperature). ``cache`` holds the base
    twin's node temperatures for the screening round."""
    sensors = base_spec.get("sensors", {})
    nt = y0.shape[1]
    if c.effect == "sensor_bias":
        col = f"{c.target}_c"
        if col not in problem.channels:
            return None
        dy = np.zeros_like(y0)
        dy[problem.channels.index(col)] = float(v[0])
        return dy
    if c.effect == "elastic_gain":
        ch, node = c.target.split("/", 1)
        if ch not in problem.channels:
            return None
        if "X" not in cache:
            m = load_machine(base_spec)
            vals = timeline_from_recording(m, problem.recording).resolved(m)
            net, _, X, _ = node_states(m, problem.recording.time_s, vals, stop=nt)
            cache["X"], cache["nodes"] = X, list(net.node_names)
        if node not in cache["nodes"]:
            return None
        x = cache["X"][:, cache["nodes"].index(node)]
        dy = np.zeros_like(y0)
        dy[problem.channels.index(ch)] = float(v[0]) * (x - x[0])
        return dy
    if c.effect == "time_lag" and c.target in sensors and not float(sensors[c.target].get("lag_s", 0.0)):
        col = f"{c.target}_c"
        t = problem.recording.time_s[:nt]
        dt = np.diff(t)
        if col not in problem.channels or nt < 2 or np.ptp(dt) > 1e-9 * abs(dt[0]):
            return None
        j = problem.channels.index(col)
        a = math.exp(-float(dt[0]) / float(v[0]))
        y = y0[j]
        lag = np.empty_like(y)
        lag[0] = y[0]
        lag[1:] = lfilter([1.0 - a], [1.0, -a], y[1:], zi=[a * y[0]])[0]
        dy = np.zeros_like(y0)
        dy[j] = lag - y
        return dy
    return None


def _starts(c: Candidate) -> list[np.ndarray]:
    """Start values: x0 plus a spread of the non-linear parameters (time constants, exponents)."""
    x0 = np.array([p.x0 for p in c.params])
    starts = [x0]
    for j, p in enumerate(c.params):
        if p.name == "tau":
            for v in (300.0, 7200.0, 21600.0):
                s = x0.copy(); s[j] = v; starts.append(s)
        elif p.name == "exponent":
            for v in (0.8, 2.0):
                s = x0.copy(); s[j] = v; starts.append(s)
        elif p.name == "T_coolant":
            for v in (14.0, 28.0):
                s = x0.copy(); s[j] = v; starts.append(s)
    return starts


def _unresolved(problem: FitProblem, c: Candidate, v: np.ndarray) -> str | None:
    """A lag shorter than half the recording's step is not resolved by its sampling (a
    reading re-sampled onto the inputs' clock is smoothed by about that much)."""
    if c.effect != "time_lag":
        return None
    step = float(np.median(np.diff(problem.recording.time_s)))
    if float(v[0]) < 0.5 * step:
        return f"tau = {float(v[0]):.4g} s below half the recording step {step:g} s: not resolved by the sampling"
    return None


def fit_candidate(problem: FitProblem, base_spec: dict, c: Candidate, y0_full: np.ndarray,
                  err_screen: float = 0.0, max_nfev: int = 60) -> Hypothesis | None:
    """Fit one candidate on the training window and score it on the held-out window."""
    nt = problem.n_train
    lo = np.array([p.lo for p in c.params])
    hi = np.array([p.hi for p in c.params])
    scale = np.maximum(np.abs([p.x0 for p in c.params]), 1e-3 * (hi - lo))

    seen: dict[bytes, np.ndarray] = {}

    def fun(v):
        # the optimiser starts by evaluating the best start value again: one twin run saved
        key = np.asarray(v, dtype=float).tobytes()
        if key not in seen:
            if len(seen) >= 8:          # the starts are what is evaluated again; keep memory small
                seen.clear()
            try:
                y = problem.outputs(c.apply(base_spec, v), stop=nt)
                seen[key] = problem.train_residual(y).ravel()
            except MachineSpecError:
                seen[key] = np.full(problem.train_residual(y0_full).size, 1e6)
        return seen[key]

    best = None
    for s in _starts(c):
        s = np.clip(s, lo, hi)
        cost = float(np.sum(fun(s) ** 2))
        if best is None or cost < best[0]:
            best = (cost, s)
    try:
        sol = least_squares(fun, best[1], bounds=(lo, hi), x_scale=scale, method="trf",
                            max_nfev=max_nfev, xtol=1e-6, ftol=1e-8)
    except (ValueError, MachineSpecError):
        return None
    v = sol.x
    spec = c.apply(base_spec, v)
    try:
        y1 = problem.outputs(spec)
    except MachineSpecError:
        return None
    r0t = problem.train_residual(y0_full)
    r1t = problem.train_residual(y1)
    r0h = problem.weighted_residual(y0_full, nt)
    r1h = problem.weighted_residual(y1, nt)
    return Hypothesis(candidate=c, values=v, spec=spec, err_screen=err_screen,
                      sse_train_before=float(np.sum(r0t ** 2)), sse_train_after=float(np.sum(r1t ** 2)),
                      sse_holdout_before=float(np.sum(r0h ** 2)), sse_holdout_after=float(np.sum(r1h ** 2)),
                      delta_bic=delta_bic(r0t, r1t, len(c.params)), reason=c.implausible(v) or _unresolved(problem, c, v),
                      n_eff_holdout=effective_samples(r1h), worse=worse_channels(problem, y0_full, y1),
                      acted_improvement_pct=acted_improvement_pct(r0h, r1h),
                      change=problem.weighted(y1[:, :nt:problem.stride] - y0_full[:, :nt:problem.stride]).ravel())
