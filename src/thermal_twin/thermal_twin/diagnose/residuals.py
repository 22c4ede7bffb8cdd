"""The residual-analysis step of a diagnosis: statistics per channel, windows, regimes.

For every channel the twin shares with the recording, the residual (measured - twin) is
tested for whiteness (Ljung-Box), drift and spectral peaks, and cross-correlated with every
driver (inputs, derived signals, the recording's sensors the twin does not model); the
channels are independent tasks of :func:`thermal_comp_common.runtime.task_engine.map_tasks`, put
back in the channels' order. Then the located windows and regime effects
(:mod:`thermal_twin.diagnose.locate`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_comp_common.recording_csv import Recording
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_twin.diagnose import locate
from thermal_twin.diagnose import statistics as stats
from thermal_twin.machine.schema import Machine

MAX_CCF_REPORTED = 5


@dataclass
class ResidualAnalysis:
    channels: dict[str, dict]      # per channel: unit, ljung_box, drift, spectral_peaks, cross_correlation
    ccf: dict[str, list]           # per channel: the significant cross-correlations, strongest first
    windows: list
    regime_effects: list


def driver_inputs(rec: Recording, machine: Machine) -> dict[str, np.ndarray]:
    """The recording's inputs, plus what the twin takes from a sensor (e.g. the ambient)."""
    out = dict(rec.inputs)
    for name, ispec in machine.inputs.items():
        col = f"{ispec.from_sensor}_c" if ispec.from_sensor else None
        if name not in out and col in rec.columns:
            out[name] = rec.columns[col]
    return out


@dataclass
class _Shared:
    time_s: np.ndarray
    resid: dict[str, np.ndarray]
    drivers: dict[str, np.ndarray]
    max_lag: int
    dt: float
    units: dict[str, str]


def _channel_task(sh: _Shared, c: str) -> tuple[list, dict]:
    """(significant cross-correlations, statistics) of one channel's residual."""
    r = sh.resid[c]
    own = {c, f"d({c})/dt"}
    cc = [stats.cross_correlation(r, u, sh.max_lag, name) for name, u in sh.drivers.items()
          if name not in own and np.nanstd(u) > 0]
    cc.sort(key=lambda x: -abs(x.peak_value) / max(x.band, 1e-12))
    top = [x for x in cc if x.significant][:MAX_CCF_REPORTED]
    return top, {"unit": sh.units[c], "ljung_box": stats.ljung_box(r), "drift": stats.drift(sh.time_s, r),
                 "spectral_peaks": stats.spectral_peaks(r, sh.dt),
                 "cross_correlation": [x.as_dict(sh.dt) for x in top]}


def analyse(rec: Recording, channels: list[str], measured: dict[str, np.ndarray], y: np.ndarray,
            units: dict[str, str], inputs: dict[str, np.ndarray], max_lag_s: float, start_hour: float,
            engine: EngineSpec | None = None) -> ResidualAnalysis:
    """Analyse the residuals of the outputs ``y`` (channels x time) against ``measured``."""
    t = rec.time_s
    dt = float(np.median(np.diff(t)))
    resid = {c: measured[c] - y[i] for i, c in enumerate(channels)}
    drivers = stats.derived_drivers(t, inputs, rec.sensors)
    drivers.update({c: stats.fill_gaps(v) for c, v in rec.sensors.items()
                    if c not in channels and np.isfinite(v).any()})
    shared = _Shared(t, resid, drivers, int(max_lag_s / dt), dt, units)
    ccf: dict[str, list] = {}
    report: dict[str, dict] = {}
    results: list = [None] * len(channels)
    for i, res in map_tasks(_channel_task, shared, channels, engine):
        results[i] = res
    for c, (top, entry) in zip(channels, results):
        ccf[c], report[c] = top, entry
    regimes = locate.operating_regimes(t, rec.inputs, start_hour)
    return ResidualAnalysis(report, ccf, locate.locate_windows(t, resid, regimes, units),
                            locate.regime_effects(resid, regimes, units))
