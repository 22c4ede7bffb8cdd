"""A prior from a machine's own history: the adaptive models' starting point fitted on its past runs.

The type's twin gives a prior in simulation (``talc_model.prior.talc`` / ``agp`` / ``cd`` on
simulated programmes); a machine that has run for months gives one from its recordings instead:
the same builders on the recorded runs (each run's errors and temperatures as deltas from its own
start, the last run held out to choose orders / inputs and to check the prior), so the file has
the same fields and integrity (identity, content hash) as a twin prior; its ``prior_source`` is
``"history"`` (in the identity block too) and ``recordings`` lists the runs it was fitted on.

The configuration comes from the recordings' columns (what is common to every run): components =
the error columns, sensors = the temperature columns; TALC and the CD model on the medoid sensors
of the temperature groups (:mod:`talc_model.open_loop.sensor_selection`), the AGP on every
temperature (ARD weighs them); TALC and the AGP also on the machine inputs every run recorded
(e.g. the spindle speed). A user configuration overrides any key. No rclpy here. docs/prior.md.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from talc_model.adaptive_model import ANGULAR_COMPONENTS
from talc_model.open_loop.sensor_selection import sensor_groups, sensor_medoids
from talc_model.prior.agp import build_agp_prior
from talc_model.prior.cd import build_cd_prior
from talc_model.prior.common import PriorError
from talc_model.prior.talc import build_talc_prior

#: the value of a history prior's ``prior_source`` (a twin prior has none)
HISTORY = "history"
KINDS = ("talc", "agp", "cd")


def _common(recordings: Sequence[Any], kind: str) -> list[str]:
    """Column names of ``kind`` ("sensor", "error", "input") present in every recording, in the
    first one's order."""
    first = recordings[0].names(kind)
    return [c for c in first if all(c in r.columns for r in recordings[1:])]


def component_name(column: str) -> str:
    """The component of an error column: ``ch1_um`` -> ``ch1``, ``E_X0C`` as it is."""
    return column[:-3] if column.endswith("_um") else column


def medoid_sensors(recordings: Sequence[Any], sensors: Sequence[str]) -> list[str]:
    """One sensor per group of correlated temperatures over all runs (deltas from each run's start)."""
    parts = []
    for r in recordings:
        t = np.column_stack([np.asarray(r.columns[f"{s}_c"], float) for s in sensors])
        ok = np.all(np.isfinite(t), axis=1)
        if ok.any():
            parts.append(t[ok] - t[ok][0])
    if not parts:
        raise PriorError("history prior: no row of any recording has every temperature")
    temps = np.vstack(parts)
    return list(sensor_medoids(temps, sensor_groups(temps).n_groups, list(sensors)))


def history_config(kind: str, recordings: Sequence[Any], overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The model configuration of ``kind`` from the recordings' common columns, ``overrides`` on top."""
    if kind not in KINDS:
        raise PriorError(f"history prior: model kind {kind!r} is none of {list(KINDS)}")
    if not recordings:
        raise PriorError("history prior: no recordings")
    errors = [component_name(c) for c in _common(recordings, "error")]
    sensors = [c[:-2] for c in _common(recordings, "sensor")]
    inputs = _common(recordings, "input")
    if not errors:
        raise PriorError(f"history prior: no error column (E_* or *_um) common to every recording "
                         f"(first: {recordings[0].source or '?'})")
    if not sensors:
        raise PriorError("history prior: no temperature column (*_c) common to every recording")
    over = dict(overrides or {})
    if kind == "talc":
        cfg = {"component_names": errors, "angular_components": [c for c in errors if c in ANGULAR_COMPONENTS],
               "input_names": over.get("input_names") or medoid_sensors(recordings, sensors) + inputs}
    elif kind == "agp":
        cfg = {"components": errors, "sensors": sensors, "machine_inputs": inputs}
    else:
        cfg = {"components": errors, "sensors": over.get("sensors") or medoid_sensors(recordings, sensors),
               "type_inputs": []}
    cfg.update(over)
    return cfg


def build_history_prior(kind: str, recordings: Sequence[Any], config: Mapping[str, Any] | None = None, *,
                        machine: str = "", sources: Sequence[str] = (), **fit) -> dict[str, Any]:
    """The prior of ``kind`` fitted on ``recordings`` (a machine's past runs, the last held out),
    configured by :func:`history_config` (``config`` overrides); ``fit``: the builder's own
    options (TALC: na_max, nb_max)."""
    if len(recordings) < 2:
        raise PriorError(f"history prior: {len(recordings)} recording(s); need at least 2 "
                         "(the last is held out to choose and check the prior)")
    names = list(sources) or [r.source or f"run {i + 1}" for i, r in enumerate(recordings)]
    if len(names) != len(recordings):
        raise PriorError(f"history prior: {len(names)} source names for {len(recordings)} recordings")
    cfg = history_config(kind, recordings, config)
    label = machine or HISTORY
    if kind == "talc":
        prior = build_talc_prior(recordings, cfg, machine=label, sources=names, **fit)
    elif kind == "agp":
        prior = build_agp_prior(recordings, cfg, machine=label, sources=names, **fit)
    else:
        prior = build_cd_prior(recordings, cfg, machine=label, sources=names, **fit)
    prior["prior_source"] = HISTORY
    prior["held_out"] = names[-1:]
    prior["run_config"] = cfg
    prior["recordings"] = [{"source": n, "rows": len(r), "hours": round(float(r.time_s[-1] - r.time_s[0]) / 3600.0, 3)}
                           for n, r in zip(names, recordings)]
    return prior
