"""Virtual experiment: replay a recording through an adaptive model, as the theses do offline.

The recording's inputs drive :class:`talc_model.loop.closed_loop.ClosedLoop`; each prediction is
applied as compensation and a probe, when the model asks, sees the residual (true - applied,
plus optional noise and resolution). A recording cannot pause, so probing time is charged in
Q_prod only. Columns: ``<id>_c`` -> sensor ``<id>``, ``E_*`` / ``<name>_um`` -> error
components (relative to the first row by default), the rest -> machine-state inputs.
See docs/talc.md for the thesis background (Blaser §6.3, AGP thesis Ch. 5-6).
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from talc_model.adaptive_model import AdaptiveModel
from talc_model.loop.closed_loop import ClosedLoop, HeldCompensation, ProbeFailed
from thermal_comp_common import metrics


class VirtualExperimentError(ValueError):
    """Bad replay input; the message names the column / component and value."""


@dataclass
class ReplayColumns:
    """Which recording column feeds which model input / error component."""

    sensors: dict[str, str]      # sensor id -> column
    inputs: dict[str, str]       # machine-state name -> column
    errors: dict[str, str]       # component -> column

    @classmethod
    def from_recording(cls, recording) -> "ReplayColumns":
        sensors = {c[:-2]: c for c in recording.names("sensor")}
        inputs = {c: c for c in recording.names("input")}
        errors = {(c[:-3] if c.endswith("_um") else c): c for c in recording.names("error")}
        errors.update({c: c for c in recording.names("error")})   # a component may be named as its column
        return cls(sensors, inputs, errors)


@dataclass
class VirtualExperimentResult:
    time_s: np.ndarray
    components: list[str]
    true: dict[str, np.ndarray]          # total (uncompensated) error, relative if requested
    predicted: dict[str, np.ndarray]     # compensation applied at each step
    std: dict[str, np.ndarray]
    residual: dict[str, np.ndarray]      # true - predicted (what remains on the part)
    phase: list[str]
    probe_times_s: list[float]
    recalibration_times_s: list[float]
    final_status: dict[str, Any]
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-friendly summary (no time series)."""
        return {"components": self.components, "steps": int(self.time_s.size),
                "duration_h": float((self.time_s[-1] - self.time_s[0]) / 3600.0) if self.time_s.size else 0.0,
                "probing_cycles": len(self.probe_times_s),
                "recalibrations": len(self.recalibration_times_s),
                "recalibration_times_h": [round(t / 3600.0, 3) for t in self.recalibration_times_s],
                "metrics": self.metrics, "final_status": self.final_status}


def component_metrics(true: np.ndarray, compensation: np.ndarray) -> dict[str, float]:
    """RMS / P2P of the uncompensated and compensated error and their reductions (AGP thesis
    Eqs 4.22-4.27, on the residual) and P99 of |residual| (TALC thesis 4.30), from
    ``thermal_comp_common.metrics`` (E = true error, E_hat = applied compensation)."""
    ok = np.isfinite(true) & np.isfinite(compensation)
    if not ok.any():
        return {}
    e, e_hat = true[ok], compensation[ok]
    zero = np.zeros_like(e)
    return {"rms_uncompensated_um": metrics.e_rms(e, zero), "rms_compensated_um": metrics.e_rms(e, e_hat),
            "rms_reduction_pct": metrics.rms_reduction(e, e_hat),
            "p2p_uncompensated_um": float(np.max(e) - np.min(e)),
            "p2p_compensated_um": float(np.max(e - e_hat) - np.min(e - e_hat)),
            "p2p_reduction_pct": metrics.p2p_reduction(e, e_hat),
            "p99_compensated_um": metrics.p99(e, e_hat)}


def probe_noise_by_component(components: Sequence[str], linear_um: float, angular_um_per_m: float,
                             angular_components: Sequence[str]) -> dict[str, float]:
    """Probe noise std per component: ``angular_um_per_m`` for the angular ones, else ``linear_um``."""
    ang = set(angular_components)
    return {c: float(angular_um_per_m if c in ang else linear_um) for c in components}


def _noise_per_component(probe_noise_um, probed: Sequence[str]) -> dict[str, float]:
    if isinstance(probe_noise_um, Mapping):
        missing = [c for c in probed if c not in probe_noise_um]
        if missing:
            raise VirtualExperimentError(f"probe_noise_um: no value for probed component(s) {missing} "
                                         f"(given: {sorted(probe_noise_um)})")
        noise = {c: probe_noise_um[c] for c in probed}
    else:
        noise = {c: probe_noise_um for c in probed}
    for c, v in noise.items():
        try:
            ok = math.isfinite(float(v)) and float(v) >= 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise VirtualExperimentError(f"probe_noise_um[{c!r}]: {v!r} must be a finite number >= 0")
    return {c: float(v) for c, v in noise.items()}



def _closest_error_column(name: str, columns: ReplayColumns) -> str:
    pool = sorted(set(columns.errors.values()))
    match = difflib.get_close_matches(name, pool, n=1, cutoff=0.3)
    return f"closest: {match[0]!r}; " if match else ""


def _check_columns(recording, columns: ReplayColumns, names: Sequence[str], probed: Sequence[str]) -> None:
    for c in names:
        if c not in columns.errors:
            raise VirtualExperimentError(f"model component {c!r} has no error column in the recording "
                                         f"({_closest_error_column(c, columns)}"
                                         f"error columns: {sorted(set(columns.errors.values()))}; a component "
                                         f"is named as its column, or without its '_um')")
    for mapping in (columns.sensors, columns.inputs, columns.errors):
        for key, col in mapping.items():
            if col not in recording.columns:
                raise VirtualExperimentError(f"column {col!r} (for {key!r}) is not in the recording")
    for c in probed:
        if c not in columns.errors:
            raise VirtualExperimentError(f"probed component {c!r} has no error column in the recording "
                                         f"({_closest_error_column(c, columns)}"
                                         f"error columns: {sorted(set(columns.errors.values()))})")


def _true_errors(recording, columns: ReplayColumns, components: Sequence[str], rows: slice,
                 relative: bool) -> dict[str, np.ndarray]:
    """The recorded errors of ``components`` over ``rows`` (relative to the first finite one)."""
    true = {}
    for c in components:
        e = np.asarray(recording.columns[columns.errors[c]][rows], dtype=float)
        if relative:
            first = e[np.isfinite(e)]
            e = e - (first[0] if first.size else 0.0)
        true[c] = e
    return true


class ReplayProbe:
    """The replay's probe: the residual at row ``row`` (true - applied) of the probed
    components, plus Gaussian noise (fixed seed), quantised to the resolution."""

    def __init__(self, true: Mapping[str, np.ndarray], probed: Sequence[str], noise: Mapping[str, float],
                 resolution_um: float, seed: int):
        self.true, self.probed, self.noise, self.resolution_um = true, list(probed), noise, resolution_um
        self.rng = np.random.default_rng(seed)
        self.row = 0

    def __call__(self, t_s: float, applied: Mapping[str, float]) -> dict[str, float]:
        measured = {}
        for c in self.probed:
            m = self.true[c][self.row] - applied.get(c, 0.0)
            if self.noise[c] > 0:
                m += self.rng.normal(0.0, self.noise[c])
            if self.resolution_um > 0:
                m = round(m / self.resolution_um) * self.resolution_um
            measured[c] = m
        if not all(math.isfinite(v) for v in measured.values()):
            raise ProbeFailed("true error not recorded at this instant")
        return measured


def run_virtual_experiment(recording, model: AdaptiveModel, *, columns: ReplayColumns | None = None,
                           probed_components: Sequence[str] | None = None,
                           probe_noise_um: float | Mapping[str, float] = 0.0,
                           probe_resolution_um: float = 0.0,
                           relative_errors: bool = True, start: int = 0, stop: int | None = None,
                           seed: int = 0, progress: bool = False,
                           compute_metrics: bool = True) -> VirtualExperimentResult:
    """Replay ``recording`` (a ``thermal_comp_common.recording_csv.Recording``) through ``model``.

    ``probed_components``: what the probe measures (default every model component with an error
    column; e.g. only the guide-bush TLS component on the lathe). Probe noise is Gaussian with
    std ``probe_noise_um`` (fixed ``seed``), then quantised to ``probe_resolution_um``.
    ``probe_noise_um`` is one value for every component or a mapping component -> std (the
    sphere cycle measures linear errors in um and angular ones in um/m with different
    uncertainties, thesis Table 5.4: see :func:`probe_noise_by_component`); a mapping must
    name every probed component.
    """
    columns = columns or ReplayColumns.from_recording(recording)
    names = list(model.component_names)
    probed = list(probed_components) if probed_components is not None else names
    _check_columns(recording, columns, names, probed)
    noise = _noise_per_component(probe_noise_um, probed)
    stop = len(recording) if stop is None else min(stop, len(recording))
    if not 0 <= start < stop:
        raise VirtualExperimentError(f"start/stop: empty range {start}..{stop} of {len(recording)} rows")
    t = recording.time_s[start:stop]
    n = t.size
    rows = slice(start, stop)
    true = _true_errors(recording, columns, sorted(set(names) | set(probed)), rows, relative_errors)
    sens = {s: np.asarray(recording.columns[col][rows], dtype=float) for s, col in columns.sensors.items()}
    inps = {s: np.asarray(recording.columns[col][rows], dtype=float) for s, col in columns.inputs.items()}
    pred = {c: np.full(n, np.nan) for c in names}
    std = {c: np.full(n, np.nan) for c in names}
    phase: list[str] = []
    probe = ReplayProbe(true, probed, noise, probe_resolution_um, seed)
    loop = ClosedLoop(model, HeldCompensation(names), probe=probe)
    steps = range(n)
    if progress:
        steps = tqdm(steps, desc=f"replay {getattr(model, 'kind', '?')}", unit="step", leave=False)
    for k in steps:
        tk = float(t[k])
        probe.row = k
        step = loop.step(tk, {s: float(v[k]) for s, v in sens.items()}, {s: float(v[k]) for s, v in inps.items()})
        for c in names:
            pred[c][k] = step.values.get(c, math.nan)
            std[c][k] = step.stds.get(c, math.nan)
        phase.append(model.status(tk).phase)
    probe_times = loop.probe_times_s
    compensation = {c: np.where(np.isfinite(pred[c]), pred[c], 0.0) for c in names}
    residual = {c: true[c] - compensation[c] for c in names}
    status = model.status(float(t[-1])).as_dict()
    result = VirtualExperimentResult(t.copy(), names, {c: true[c] for c in names}, pred, std, residual, phase,
                                     probe_times, list(getattr(model, "recalibration_times", [])), status)
    if compute_metrics:
        result.metrics = {c: component_metrics(true[c], compensation[c]) for c in names}
    return result


def plot_virtual_experiment(result: VirtualExperimentResult, path, title: str = "",
                            sigma_max: float | None = None) -> None:
    """PNG of true error, compensation, residual and predictive std per component (Agg)."""
    # imported here: the Agg backend must be chosen before pyplot loads, and replays need no plots
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after choosing the Agg backend
    comps = result.components
    fig, axes = plt.subplots(2, len(comps), figsize=(6 * len(comps), 6), sharex=True, squeeze=False)
    th = result.time_s / 3600.0
    for j, c in enumerate(comps):
        ax = axes[0][j]
        ax.plot(th, result.true[c], label="true error", lw=1)
        ax.plot(th, result.predicted[c], label="compensation", lw=1)
        ax.plot(th, result.residual[c], label="residual", lw=1)
        for tr in result.recalibration_times_s:
            ax.axvline(tr / 3600.0, color="0.7", lw=0.5)
        ax.set_title(f"{title} {c}".strip())
        ax.set_ylabel("um")
        ax.legend(loc="best", fontsize=8)
        ax = axes[1][j]
        ax.plot(th, result.std[c], label="predictive std", lw=1)
        if sigma_max is not None:
            ax.axhline(sigma_max, color="r", ls="--", lw=1, label="sigma_max")
        ax.set_xlabel("time (h)")
        ax.set_ylabel("um")
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
