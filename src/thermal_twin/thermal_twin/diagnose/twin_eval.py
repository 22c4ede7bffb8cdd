"""Noise-free evaluation of the twin for the mismatch finder's fitting loop.

The finder simulates the twin hundreds of times per diagnosis (every candidate effect,
every least-squares iteration). :func:`thermal_twin.sim.simulate.simulate` is the reference
but steps through Python dictionaries; :func:`expected_outputs` computes the same
noise-free outputs with the twin's own parts (:class:`ThermalNetwork` step matrices,
``initial_temperatures``, the sensor bank's weights/lag/gain/bias and the error map),
vectorising everything: within a run of one conductance regime the state recursion
decouples into scalar modal recursions run by ``scipy.signal.lfilter``. The exact step
maps come from the symmetric eigen-decomposition of C^-1/2 K C^-1/2 (closed form of the
same zero-order hold the twin computes with ``expm``), cached across calls because most
candidate effects leave the conductances alone. On a regular grid it
implements exactly the semantics of ``simulate`` (inputs hold from ``time_s[k]``, periodic
sources at mid-step, first-order sensor lag, errors relative to t = 0); a test checks it
against ``simulate`` to 1e-9. Rows a recording dropped are put back with interpolated inputs
(:func:`gap_filled`) instead of holding the last row's inputs across the gap. Sensor noise and quantisation are left out on purpose: the finder
compares the recording with the expected reading.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from typing import Mapping

import numpy as np
from scipy.signal import lfilter

from thermal_twin.machine.schema import Machine
from thermal_twin.physics.sensor_model import SensorBank
from thermal_twin.sim.simulate import initial_temperatures
from thermal_twin.physics.thermal_network import ThermalNetwork
from thermal_twin.physics.thermo_elastic import ErrorMap


_STEP_CACHE: OrderedDict = OrderedDict()
_STEP_CACHE_SIZE = 4096
_SHORT_RUN_PER_NODE = 8      # runs up to 8 steps per node are stepped directly (see node_states)


def step_maps(K: np.ndarray, capacity: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """(Phi, Psi, L, R, lam) of x' = -C^-1 K x + f held for ``dt``: Phi = exp(A dt),
    Psi = int_0^dt exp(A s) ds, and the modal form Phi = L diag(lam) R with R = L^-1.

    With S = C^-1/2 K C^-1/2 = Q diag(mu) Q^T: Phi = C^-1/2 Q e^(-mu dt) Q^T C^1/2 and
    Psi = C^-1/2 Q ((1 - e^(-mu dt))/mu) Q^T C^1/2 (dt where mu = 0)."""
    key = (K.tobytes(), capacity.tobytes(), round(float(dt), 9))
    hit = _STEP_CACHE.get(key)
    if hit is not None:
        _STEP_CACHE.move_to_end(key)
        return hit
    ih = 1.0 / np.sqrt(capacity)
    S = ih[:, None] * K * ih[None, :]
    mu, Q = np.linalg.eigh(0.5 * (S + S.T))
    e = np.exp(-mu * dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        integ = np.where(np.abs(mu * dt) > 1e-12, -np.expm1(-mu * dt) / mu, dt)
    left = ih[:, None] * Q
    right = Q.T * np.sqrt(capacity)[None, :]
    hit = ((left * e) @ right, (left * integ) @ right, left, right, e)
    _STEP_CACHE[key] = hit
    if len(_STEP_CACHE) > _STEP_CACHE_SIZE:
        _STEP_CACHE.popitem(last=False)
    return hit


def expected_outputs(machine: Machine, time_s: np.ndarray, inputs: Mapping[str, np.ndarray],
                     stop: int | None = None) -> dict[str, np.ndarray]:
    """Noise-free sensor readings (``<id>_c``) and error components of ``machine`` for the
    resolved input arrays ``inputs`` (every machine input present), over ``time_s[:stop]``."""
    net, t, X, tb = node_states(machine, time_s, inputs, stop)
    return outputs_from_states(machine, net, t, X, tb)


def gap_filled(time_s: np.ndarray, values: Mapping[str, np.ndarray]
               ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray] | None:
    """The time grid with the rows a recording dropped put back, or None on a regular grid.

    The nominal step is the grid's own median step; a step of m + 1 nominal steps (rounded,
    so a jittered regular grid never counts) hides m rows. They are put back at equal
    spacing with every input interpolated linearly between the rows around the gap: an input
    that switches once at an unknown instant of the gap has that ramp as its expected value
    (a zero-order hold from the last row assumes the latest switch, which doubles the
    expected squared error of a step and lags a continuously varying input by the gap).
    Returns (time, inputs, rows): ``rows`` index the original instants in the filled grid."""
    t = np.asarray(time_s, dtype=float)
    if t.size < 3:
        return None
    dt = np.diff(t)
    hidden = np.rint(dt / np.median(dt)).astype(np.int64) - 1
    if not np.any(hidden >= 1):
        return None
    parts = np.maximum(hidden, 0) + 1                      # sub-steps per original step
    step = np.repeat(np.arange(dt.size), parts)
    first = np.concatenate([[0], np.cumsum(parts)[:-1]])
    frac = (np.arange(step.size) - np.repeat(first, parts)) / np.repeat(parts, parts)
    t_new = np.concatenate([t[step] + frac * dt[step], t[-1:]])
    vals = {}
    for k, v in values.items():
        a = np.asarray(v, dtype=float)
        vals[k] = np.concatenate([a[step] + frac * (a[step + 1] - a[step]), a[-1:]])
    rows = np.concatenate([first, [step.size]])
    return t_new, vals, rows


def gap_envelope(machine: Machine, time_s: np.ndarray, inputs: Mapping[str, np.ndarray]
                 ) -> dict[str, np.ndarray] | None:
    """How much the unknown instants of input changes inside gaps of dropped rows can move
    each output (None on a regular grid): per gap across which an input changed, |outputs
    with that change at the gap's first missing instant - outputs with it at the gap's end|,
    summed over the gaps (the gaps' effects add up or cancel depending on where each change
    truly was). The truth lies within it; the interpolated inputs of :func:`node_states`
    meet it half-way on average, so where the envelope is large no twin can be compared
    with the reading."""
    t = np.asarray(time_s, dtype=float)
    vals = {k: np.asarray(inputs[k], dtype=float)[:t.size] for k in machine.inputs}
    filled = gap_filled(t, vals)
    if filled is None:
        return None
    t_fill, _, rows = filled
    step = np.searchsorted(rows, np.arange(t_fill.size), side="right") - 1
    inserted = np.ones(t_fill.size, dtype=bool)
    inserted[rows] = False
    changed = np.zeros(t.size, dtype=bool)
    changed[:-1] = np.any([np.diff(v) != 0 for v in vals.values()], axis=0) if vals else False
    after = np.minimum(step + 1, t.size - 1)

    def outputs(pick: np.ndarray) -> dict[str, np.ndarray]:
        net, _, X, tb = _held_states(machine, t_fill, {k: v[pick] for k, v in vals.items()})
        return outputs_from_states(machine, net, t, X[rows], tb[rows])
    late = outputs(step)
    env = {k: np.zeros(t.size) for k in late}
    for g in np.unique(step[inserted & changed[step]]):
        early = outputs(np.where(inserted & (step == g), after, step))
        for k in env:
            env[k] += np.abs(early[k] - late[k])
    return env


def gap_uncertain_readings(machine: Machine, time_s: np.ndarray, inputs: Mapping[str, np.ndarray],
                           channels: list[str], sigma: Mapping[str, float]) -> np.ndarray | None:
    """The readings (channels x time, True: leave out) no twin can be compared with: after a gap
    of dropped rows across which an input changed, where the twin's uncertainty from the unknown
    instant of the change exceeds the channel's noise ``sigma``. An instant uniform within the
    gap moves the output uniformly within :func:`gap_envelope`, a standard deviation of
    envelope / sqrt(12). None on a regular grid. The one rule every command that fits or scores
    a twin on a recording applies (diagnose, calibrate)."""
    env = gap_envelope(machine, time_s, inputs)
    if env is None:
        return None
    return np.stack([env[c] / math.sqrt(12.0) > sigma[c] for c in channels])


def node_states(machine: Machine, time_s: np.ndarray, inputs: Mapping[str, np.ndarray],
                stop: int | None = None) -> tuple[ThermalNetwork, np.ndarray, np.ndarray, np.ndarray]:
    """(network, time, node temperatures X (time x nodes), boundary temperatures (time x
    boundaries)) of ``machine`` for the resolved ``inputs`` over ``time_s[:stop]``; the
    calibration needs X for the error gains' exact derivatives.

    Inputs hold from each row to the next (the twin's zero-order hold), except across rows a
    recording dropped: there the twin steps through the missing instants with interpolated
    inputs (:func:`gap_filled`) and X is returned at the recorded instants only."""
    t = np.asarray(time_s, dtype=float)[:stop]
    vals = {k: np.asarray(inputs[k], dtype=float)[:t.size] for k in machine.inputs}
    filled = gap_filled(t, vals)
    if filled is None:
        return _held_states(machine, t, vals)
    t_fill, vals_fill, rows = filled
    net, _, X, tb = _held_states(machine, t_fill, vals_fill)
    return net, t, X[rows], tb[rows]


def _held_states(machine: Machine, t: np.ndarray, vals: dict[str, np.ndarray]
                 ) -> tuple[ThermalNetwork, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`node_states` with every input held from its row to the next."""
    n_t = t.size
    net = ThermalNetwork(machine)
    n = net.n

    # conductance regimes and step lengths -------------------------------------------
    dt = np.diff(t)
    vary = [(i, pu, e) for l in machine.links.values() for i, pu, e in l.varies_with]
    key_cols = [np.round(dt, 9)] + [vals[i][:-1] for i, _, _ in vary] if n_t > 1 else []
    if n_t > 1:
        # regimes change rarely: label the runs of constant key, then map runs to ids
        keys = np.column_stack(key_cols)
        starts = np.concatenate([[0], np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1])
        _, first, run_id = np.unique(keys[starts], axis=0, return_index=True, return_inverse=True)
        run_id = np.asarray(run_id).ravel()
        lengths = np.diff(np.concatenate([starts, [n_t - 1]]))
        reg = np.repeat(run_id, lengths)
        uniq = list(starts[first])          # per regime: the first step in it
    else:
        uniq, reg = [], np.zeros(0, dtype=int)
    names = list(vals)
    maps = []
    kbs = np.empty((len(uniq), n, len(net.boundary_names)))
    for r in range(len(uniq)):
        k = int(uniq[r])
        u = {name: float(vals[name][k]) for name in names}
        K, kbs[r] = net.matrices(u)
        maps.append(step_maps(K, net.capacity, float(t[k + 1] - t[k])))

    # boundary temperatures and source powers, vectorised --------------------------------
    tb = np.empty((n_t, len(net.boundary_names)))
    for j, b in enumerate(net.boundary_names):
        temp = machine.boundaries[b].temperature
        tb[:, j] = vals[temp] if isinstance(temp, str) else temp
    x0 = initial_temperatures(net, {name: float(vals[name][0]) for name in names})
    X = np.empty((n_t, n))
    X[0] = x0
    if n_t > 1:
        tm = t[:-1] + 0.5 * dt
        P = np.zeros((n_t - 1, n))
        node_index = {nm: i for i, nm in enumerate(net.node_names)}
        for s in machine.sources.values():
            p = np.full(n_t - 1, s.power)
            if s.input is not None:
                p = p + s.coefficient * np.abs(vals[s.input][:-1]) ** s.exponent
            if s.periodic_amplitude:
                p = p + s.periodic_amplitude * np.sin(2 * math.pi * (tm - s.periodic_phase_s)
                                                      / s.periodic_period_s)
            P[:, node_index[s.node]] += p
        g = np.empty((n_t - 1, n))
        for r in range(len(uniq)):
            sel = reg == r
            f = (tb[:-1][sel] @ kbs[r].T + P[sel]) / net.capacity
            g[sel] = f @ maps[r][1].T
        # x_{k+1} = Phi_r x_k + g_k; over a run of one regime the modes z = R x decouple
        # into scalar recursions z_{k+1} = lam z_k + R g_k, each run by lfilter
        change = np.flatnonzero(np.diff(reg)) + 1
        bounds = np.concatenate([[0], change, [n_t - 1]])
        x = x0
        for a, b in zip(bounds[:-1], bounds[1:]):
            _, _, L, R, lam = maps[reg[a]]
            h = g[a:b] @ R.T
            z = np.empty_like(h)
            z0 = R @ x
            if b - a <= _SHORT_RUN_PER_NODE * n:
                # a short run: one vector step per sample costs less than n lfilter calls
                zk = z0
                for k in range(b - a):
                    zk = lam * zk + h[k]
                    z[k] = zk
            else:
                for i in range(n):
                    z[:, i] = lfilter([1.0], [1.0, -lam[i]], h[:, i], zi=[lam[i] * z0[i]])[0]
            X[a + 1:b + 1] = z @ L.T
            x = X[b]
    return net, t, X, tb


def outputs_from_states(machine: Machine, net: ThermalNetwork, t: np.ndarray, X: np.ndarray,
                        tb: np.ndarray) -> dict[str, np.ndarray]:
    """Noise-free sensor readings and error components from node and boundary temperatures
    (errors relative to ``X[0]``)."""
    n_t = len(t)
    dt = np.diff(t)
    x0 = X[0]
    out: dict[str, np.ndarray] = {}
    bank = SensorBank(machine, net.node_names, net.boundary_names)
    if bank.ids:
        true = np.concatenate([X, tb], axis=1) @ bank.weights.T
        lagged = true.copy()
        lagged_cols = np.flatnonzero(bank.lag_s > 0)
        if lagged_cols.size and n_t > 1:
            a = np.exp(-dt[:, None] / bank.lag_s[lagged_cols][None, :])
            tr = true[:, lagged_cols]
            # constant step (to 1e-9 relative: a recording's float times jitter in the last
            # digits, which the Python loop below would pay for with ~50 ms per run)
            if np.ptp(dt) <= 1e-9 * abs(dt[0]):
                for j, col in enumerate(lagged_cols):
                    aj = a[0, j]
                    lagged[1:, col] = lfilter([1.0 - aj], [1.0, -aj], tr[1:, j], zi=[aj * tr[0, j]])[0]
            else:
                y = tr[0].copy()
                for k in range(1, n_t):
                    y = a[k - 1] * y + (1.0 - a[k - 1]) * tr[k]
                    lagged[k, lagged_cols] = y
        readings = bank.gain * lagged + bank.bias
        for j, sid in enumerate(bank.ids):
            out[bank.columns[j]] = readings[:, j]
    emap = ErrorMap(machine, net.node_names)
    if emap.names:
        E = emap.errors(X, x0)
        for j, e in enumerate(emap.names):
            out[e] = E[:, j]
    return out
