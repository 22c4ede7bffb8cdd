"""Estimate an input the recording lacks (spindle speed, a switch) from the temperatures.

When the twin's sources are driven by an input the recording does not have, the twin
would run with the input's default (usually 0: no heat). Instead the total heat P(t) of
those sources is estimated as a piecewise-constant profile (blocks of ``block_s``) by a
regularised linear inverse: the twin is linear in its source powers, so every block's
1 W pulse is simulated once (one twin run per block) and the channels' misfit is
``y - y_base = sum_b G_b p_b + offsets``. Each channel is scaled by its misfit's spread,
``p >= 0``, and a first-difference (Tikhonov) penalty lam ||D p||^2 is chosen by blocked
cross-validation over contiguous time chunks (thermal residuals are autocorrelated, so
chunks, not single rows, are left out). The heat is first split over the sources in the
ratio of their powers at half the input's range; then it is *located*: the estimated profile
is placed on each node in turn and non-negative weights say which nodes the temperatures
put it on (a twin that lacks the bearing source would otherwise have all the heat put on
the motor, its only speed-driven source left), and the profile is estimated again with that
split. The input equivalent to the heat on the nodes of the twin's own sources is found by
inverting sum c_i u^n_i; heat located elsewhere is reported as such (a heat input at that
node the twin lacks). A recorded boundary that the missing heat itself warms (a jacket's
coolant return) can be declared a *response* for the estimation (:func:`as_responses`: held at
its low level, its sensor not fitted), so that it does not carry the heat's signal into the
twin as a boundary. Details and limits: docs/calibrate.md.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from thermal_twin.sim.inputs_timeline import timeline_from_recording
from thermal_twin.machine.schema import Machine, load_machine
from thermal_twin.diagnose.fit import effective_samples
from thermal_twin.diagnose.twin_eval import expected_outputs
from thermal_comp_common.recording_csv import Recording

HEAT_INPUT = "estimated_heat_w"      # auxiliary input of the twin during the estimation
LAMBDAS = np.logspace(-4, 4, 17)     # relative to trace(A'A)/trace(D'D)
REWEIGHT = 0                         # default re-weightings of the channels by the fit's residual spread
MIN_OWN_SHARE = 0.1                  # below: the twin's own sources cannot carry the located heat


class InputEstimationError(ValueError):
    """The input cannot be estimated (no source driven by it, no channel); names the cause."""


@dataclass
class InputEstimate:
    input: str
    sources: dict[str, float]           # source name -> share of the heat
    block_edges_s: np.ndarray           # len(blocks) + 1
    power_w: np.ndarray                 # heat per block [W]
    power_ci95_w: np.ndarray            # (blocks, 2)
    equivalent_input: np.ndarray        # per block, in the input's unit
    lam: float
    cv_curve: list[tuple[float, float]]  # (lambda, cross-validated SSE)
    channels: list[str]
    tau: float
    located: dict[str, float] = field(default_factory=dict)   # node -> share the temperatures point to
    own_share: float = 1.0              # share of the heat on the nodes of the twin's own sources
    scale_identified: bool = True       # False: the temperatures put < MIN_OWN_SHARE on those nodes

    def input_series(self, time_s: np.ndarray) -> np.ndarray:
        """The equivalent input at every instant (block value)."""
        k = np.clip(np.searchsorted(self.block_edges_s, time_s, side="right") - 1, 0, len(self.power_w) - 1)
        return self.equivalent_input[k]

    def as_dict(self) -> dict:
        return {"input": self.input, "sources": self.sources, "block_s": float(np.diff(self.block_edges_s)[0]),
                "lambda": self.lam, "channels": self.channels, "located": self.located,
                "own_share": self.own_share, "scale_identified": self.scale_identified,
                "mean_power_w": float(np.mean(self.power_w)), "max_power_w": float(np.max(self.power_w)),
                "profile": [{"start_s": float(a), "power_w": float(p), "ci95_w": [float(lo), float(hi)],
                             "equivalent_input": float(u)}
                            for a, p, (lo, hi), u in zip(self.block_edges_s[:-1], self.power_w,
                                                         self.power_ci95_w, self.equivalent_input)],
                "cv_curve": [{"lambda": l, "cv_sse": s} for l, s in self.cv_curve]}


def missing_inputs(machine: Machine, rec: Recording) -> list[str]:
    """Machine inputs that drive a source and that the recording cannot supply."""
    driving = {s.input for s in machine.sources.values() if s.input}
    return [n for n, s in machine.inputs.items() if n in driving and n not in rec.columns
            and not (s.from_sensor and f"{s.from_sensor}_c" in rec.columns)]


def _heat_spec(machine: Machine, name: str) -> tuple[dict, dict, dict[str, float]]:
    """(spec without the input's sources, spec with them driven by the auxiliary heat
    input, shares); shares are the sources' powers at half the input's range."""
    spec = machine.to_dict()
    srcs = {k: s for k, s in machine.sources.items() if s.input == name}
    u_ref = 0.5 * machine.inputs[name].max
    p_ref = {k: s.coefficient * u_ref ** s.exponent for k, s in srcs.items()}
    total = sum(p_ref.values())
    if total <= 0:
        raise InputEstimationError(f"input '{name}': its sources give no heat at {u_ref:g}")
    share = {k: v / total for k, v in p_ref.items()}
    base = copy.deepcopy(spec)
    for k in srcs:
        del base["sources"][k]
    pulse = copy.deepcopy(base)
    pulse["inputs"][HEAT_INPUT] = {"kind": "machine", "unit": "W", "default": 0.0, "min": 0.0, "max": 1e12}
    for k, s in srcs.items():
        pulse["sources"][f"est_{k}"] = {"node": s.node, "input": HEAT_INPUT, "coefficient": share[k], "exponent": 1.0}
    return base, pulse, share


def _outputs(spec: dict, rec: Recording, channels: list[str], extra: dict | None = None) -> np.ndarray:
    m = load_machine(spec)
    tl = timeline_from_recording(m, rec)
    vals = tl.resolved(m) if not extra else {**tl.resolved(m), **extra}
    out = expected_outputs(m, rec.time_s, vals)
    return np.stack([out[c] for c in channels])


def as_responses(machine: Machine, rec: Recording, channels: list[str], responses: list[str],
                 quantile: float = 0.05) -> tuple[Recording, list[str]]:
    """The recording and channels for an estimation in which the boundary inputs
    ``responses`` are *responses*, not drivers: a recorded boundary temperature that the
    missing heat itself warms (a jacket's coolant *return* rises with the motor's losses)
    would otherwise feed the heat's signal into the twin as a boundary, and the inverse
    would find no heat to estimate. Each is held at its ``quantile`` of the recording (the
    return is lowest when no heat flows into the jacket: about the supply temperature), and
    its sensor leaves the estimation's channels."""
    cols = dict(rec.columns)
    drop = set()
    for name in responses:
        if name not in machine.inputs:
            raise InputEstimationError(f"response input '{name}': not an input of twin '{machine.name}' "
                                       f"(inputs {sorted(machine.inputs)})")
        sensor = machine.inputs[name].from_sensor
        col = f"{sensor}_c" if sensor and f"{sensor}_c" in cols else (name if name in cols else None)
        if col is None:
            raise InputEstimationError(f"response input '{name}': the recording has neither column '{name}' "
                                       f"nor its sensor's column")
        level = float(np.nanquantile(np.asarray(cols[col], dtype=float), quantile))
        cols[col] = np.full(len(rec), level)
        drop.add(col)
    held = Recording(rec.time_s, cols, source=rec.source, warnings=list(rec.warnings))
    return held, [c for c in channels if c not in drop]


def estimate_input(machine: Machine, rec: Recording, name: str, channels: list[str],
                   block_s: float = 1800.0, folds: int = 5, stride: int = 0, locate: bool = True,
                   reweight: int = REWEIGHT, responses: list[str] = ()) -> InputEstimate:
    """Estimate the heat of the sources driven by ``name`` from ``channels`` of ``rec``.
    ``locate``: then find which nodes the temperatures put that heat on (:func:`locate_heat`)
    and estimate the profile again with that split. ``reweight``: see :func:`_profile`
    (0 by default: re-weighting raises the block-heat correlation only slightly and narrows the
    95 % band below the truth in many blocks; docs/calibrate.md).
    ``responses``: boundary inputs treated as responses during the estimation (:func:`as_responses`)."""
    if not any(s.input == name for s in machine.sources.values()):
        raise InputEstimationError(f"input '{name}': no source of twin '{machine.name}' is driven by it")
    if responses:
        rec, channels = as_responses(machine, rec, channels, list(responses))
    base, pulse, share = _heat_spec(machine, name)
    t = rec.time_s
    edges = np.arange(t[0], t[-1] + block_s, block_s)
    y_meas = np.stack([np.asarray(rec.columns[c], dtype=float) for c in channels])
    y_base = _outputs(base, rec, channels)
    stride = stride or max(1, len(t) // 2000)
    rows = np.arange(0, len(t), stride)
    miss = (y_meas - y_base)[:, rows]
    valid = np.isfinite(miss)
    prob = {"rec": rec, "channels": channels, "rows": rows, "valid": valid, "miss": np.where(valid, miss, 0.0),
            "y_base": y_base, "edges": edges, "folds": folds,
            "scale": np.array([np.nanstd(m) if np.nanstd(m) > 0 else 1.0 for m in miss])}
    scale0 = prob["scale"]
    sol = _profile(pulse, prob, reweight)
    located: dict[str, float] = {}
    if locate:
        located = locate_heat(base, _block_series(t, edges, sol[0]), prob)
        if located:
            pulse = _located_pulse(base, located)
            prob["scale"] = scale0
            sol = _profile(pulse, prob, reweight)
    power, ci, lam, curve, tau = sol
    own = _own_share(machine, name, located)
    return InputEstimate(name, share, edges, power, ci, equivalent_input(machine, name, power * own),
                         float(lam), curve, list(channels), float(tau), located, own,
                         scale_identified=not located or _own_nodes_share(machine, name, located) >= MIN_OWN_SHARE)


def _block_series(t: np.ndarray, edges: np.ndarray, power: np.ndarray) -> np.ndarray:
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(power) - 1)
    return power[k]


def _located_pulse(base: dict, located: dict[str, float]) -> dict:
    """The ablated description with the auxiliary heat input split over ``located`` nodes."""
    pulse = copy.deepcopy(base)
    pulse["inputs"][HEAT_INPUT] = {"kind": "machine", "unit": "W", "default": 0.0, "min": 0.0, "max": 1e12}
    for node, w in located.items():
        pulse["sources"][f"est_{node}"] = {"node": node, "input": HEAT_INPUT, "coefficient": w, "exponent": 1.0}
    return pulse


def _own_share(machine: Machine, name: str, located: dict[str, float]) -> float:
    """The share of the located heat on nodes that carry a source driven by ``name`` (what
    the twin's own sources turn into the equivalent input); 1 without a location. Below
    MIN_OWN_SHARE the twin's sources cannot carry the heat and the whole heat is inverted."""
    if not located:
        return 1.0
    own = _own_nodes_share(machine, name, located)
    return own if own >= MIN_OWN_SHARE else 1.0


def _own_nodes_share(machine: Machine, name: str, located: dict[str, float]) -> float:
    nodes = {s.node for s in machine.sources.values() if s.input == name}
    return sum(w for n, w in located.items() if n in nodes)


def locate_heat(base: dict, heat: np.ndarray, prob: tuple, min_share: float = 0.05) -> dict[str, float]:
    """Which nodes the temperatures put an estimated heat profile ``heat`` (W, per row) on:
    the profile is placed on each node in turn (one twin run per node), and non-negative
    weights (plus a free offset per channel) fit the channels' misfit. Returns node -> share
    of the heat (shares below ``min_share`` dropped, the rest renormalised); {} if no node
    takes any."""
    rec, channels, rows, valid, y_base, scale = (prob[k] for k in ("rec", "channels", "rows", "valid",
                                                                    "y_base", "scale"))
    yv = prob["miss"] / scale[:, None]
    nodes = list(base["nodes"])
    nc, nr = len(channels), len(rows)
    cols = []
    for node in nodes:
        spec = _located_pulse(base, {node: 1.0})
        dy = _outputs(spec, rec, channels, {HEAT_INPUT: heat})[:, rows] - y_base[:, rows]
        cols.append((np.where(valid, dy, 0.0) / scale[:, None]).ravel())
    off = np.zeros((nc * nr, nc))
    for c in range(nc):
        off[c * nr:(c + 1) * nr, c] = valid[c]
    A = np.column_stack(cols + [off])
    lb = np.concatenate([np.zeros(len(nodes)), np.full(nc, -np.inf)])
    w = lsq_linear(A, yv.ravel(), bounds=(lb, np.full(len(lb), np.inf))).x[:len(nodes)]
    if w.sum() <= 0:
        return {}
    keep = {n: float(x) for n, x in zip(nodes, w / w.sum()) if x / w.sum() >= min_share}
    tot = sum(keep.values())
    return {n: x / tot for n, x in keep.items()}


def _profile(pulse: dict, prob: dict, reweight: int = REWEIGHT):
    """The regularised, non-negative block profile of the heat of ``pulse``'s auxiliary
    sources: (power per block, its 95 % band, lambda, the CV curve, the residual's
    correlation time in samples). Channels are weighted by the spread of what the heat does
    *not* explain (iteratively: first the misfit's spread, then ``reweight`` times the fit's
    residual spread; the misfit's own spread would down-weight exactly the channels the
    missing heat moves most); the final weights are left in ``prob["scale"]``."""
    rec, channels, rows, valid, y_base, edges = (prob[k] for k in ("rec", "channels", "rows", "valid",
                                                                   "y_base", "edges"))
    t = rec.time_s
    nb, nc = len(edges) - 1, len(channels)
    # design: one column per block (1 W pulse), then one offset per channel
    A0 = np.zeros((nc, len(rows), nb + nc))
    for b in range(nb):
        u = ((t >= edges[b]) & (t < edges[b + 1])).astype(float)
        A0[:, :, b] = _outputs(pulse, rec, channels, {HEAT_INPUT: u})[:, rows] - y_base[:, rows]
    for c in range(nc):
        A0[c, :, nb + c] = 1.0
    A0 = np.where(valid[:, :, None], A0, 0.0)
    D = np.zeros((nb - 1, nb + nc))
    D[np.arange(nb - 1), np.arange(nb - 1)] = -1.0
    D[np.arange(nb - 1), np.arange(1, nb)] = 1.0
    DtD = D.T @ D
    chunk = (np.searchsorted(edges, t[rows], side="right") - 1) % prob["folds"]
    for it in range(reweight + 1):
        scale = prob["scale"]
        A = A0 / scale[:, None, None]
        yv = prob["miss"] / scale[:, None]
        AtA = np.einsum("cri,crj->ij", A, A)
        Aty = np.einsum("cri,cr->i", A, yv)
        lam, curve = _cv_lambda(A, yv, AtA, Aty, DtD, chunk, nb)
        # constrained solve p >= 0 on the small equivalent system [chol(A'A); sqrt(lam) D]
        R = np.linalg.cholesky(AtA + 1e-12 * np.eye(nb + nc)).T
        z = np.linalg.solve(R.T, Aty)
        lb = np.concatenate([np.zeros(nb), np.full(nc, -np.inf)])
        p = lsq_linear(np.vstack([R, np.sqrt(lam) * D]), np.concatenate([z, np.zeros(nb - 1)]),
                       bounds=(lb, np.full(nb + nc, np.inf))).x
        r = yv - A @ p
        if it < reweight:
            n_valid = np.maximum(valid.sum(axis=1), 1)
            rms = np.sqrt(np.sum(r ** 2, axis=1) / n_valid) * scale
            prob["scale"] = np.maximum(rms, 1e-6 * max(float(np.max(rms)), 1e-12))
    tau = max(1.0, r.size / effective_samples(r))
    s2 = float(np.sum(r ** 2)) / max(r.size - nb - nc, 1)
    Hinv = np.linalg.inv(AtA + lam * DtD + 1e-12 * np.eye(nb + nc))
    cov = s2 * tau * Hinv @ AtA @ Hinv
    sd = np.sqrt(np.clip(np.diag(cov)[:nb], 0, None))
    power = p[:nb]
    ci = np.column_stack([np.maximum(power - 1.96 * sd, 0.0), power + 1.96 * sd])
    return power, ci, lam, curve, tau


def _cv_lambda(A, yv, AtA, Aty, DtD, chunk, nb: int) -> tuple[float, list[tuple[float, float]]]:
    """Lambda by blocked cross-validation: folds of interleaved chunks one block long (a
    left-out chunk's heat is still seen by the rows after it, as it would be at a new time)."""
    n = AtA.shape[0]
    ref = np.trace(AtA[:nb, :nb]) / max(np.trace(DtD), 1e-300)
    curve = []
    for lam in LAMBDAS * ref:
        sse = 0.0
        for f in range(int(chunk.max()) + 1):
            sel = chunk == f
            Af, yf = A[:, sel, :], yv[:, sel]
            M = AtA - np.einsum("cri,crj->ij", Af, Af) + lam * DtD + 1e-12 * np.eye(n)
            p = np.linalg.solve(M, Aty - np.einsum("cri,cr->i", Af, yf))
            sse += float(np.sum((yf - Af @ p) ** 2))
        curve.append((float(lam), sse))
    return min(curve, key=lambda x: x[1])[0], curve


def source_power(machine: Machine, name: str, u: np.ndarray) -> np.ndarray:
    """Total heat of the sources driven by input ``name`` at input values ``u``."""
    u = np.abs(np.asarray(u, dtype=float))
    return sum(s.coefficient * u ** s.exponent for s in machine.sources.values() if s.input == name)


def equivalent_input(machine: Machine, name: str, power: np.ndarray) -> np.ndarray:
    """The input value whose sources give ``power`` (monotone inversion on a fine grid),
    clipped to the input's declared range."""
    spec = machine.inputs[name]
    grid = np.linspace(max(spec.min, 0.0), spec.max, 4001)
    pg = source_power(machine, name, grid)
    return np.interp(power, pg, grid)


def fill_missing_inputs(machine: Machine, rec: Recording, channels: list[str], block_s: float = 1800.0,
                        responses: list[str] = ()) -> tuple[Recording, list[InputEstimate], list[str]]:
    """The recording with every missing source-driving input replaced by its estimate
    (the equivalent input of the estimated heat), the estimates and one finding each.
    ``responses``: boundary inputs that the missing heat warms, held during the estimation
    (:func:`as_responses`); the returned recording keeps them as recorded."""
    cols = dict(rec.columns)
    ests, notes = [], []
    for name in missing_inputs(machine, rec):
        e = estimate_input(machine, rec, name, channels, block_s=block_s, responses=responses)
        cols[name] = e.input_series(rec.time_s)
        ests.append(e)
        split = e.located or e.sources
        srcs = ", ".join(f"{k} {100 * v:.0f} %" for k, v in split.items())
        where = "located by the temperatures on" if e.located else "split"
        notes.append(f"input '{name}' is not in the recording: estimated from the temperatures as a heat "
                     f"input of {np.mean(e.power_w):.0f} W on average (max {np.max(e.power_w):.0f} W, "
                     f"{block_s / 60:.0f}-min blocks, {where} {srcs}), i.e. {name} of "
                     f"{np.mean(e.equivalent_input):.0f} {machine.inputs[name].unit} on average"
                     + (f" from the {100 * e.own_share:.0f} % on the nodes of its sources" if e.own_share < 1 else "")
                     + ("" if e.scale_identified else
                        f" (the temperatures put under {100 * MIN_OWN_SHARE:.0f} % of the heat on the nodes of the "
                        f"twin's {name}-driven sources: the scale of {name} is not identified, the equivalent "
                        f"value makes them carry all of the heat; compare heats, not {name})")
                     + (f", with {', '.join(responses)} treated as a response (held at its 5 % level)"
                        if responses else "")
                     + "; "
                     f"profile and 95 % band in input_estimate_{name}.png")
    return Recording(rec.time_s, cols, source=rec.source, warnings=list(rec.warnings)), ests, notes
