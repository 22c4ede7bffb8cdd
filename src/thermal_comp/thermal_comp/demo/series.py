"""Time series of a demo run decoded from its bag: ground truth, predictions, probing instants,
model status and the offsets the CNC held, the input of the demo's evaluation and plot."""
from __future__ import annotations

import math
import pathlib
import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message

from thermal_comp.demo.cell import DemoError
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_msgs.msg import AxisOffsets, ModelStatus, ThermalErrors

_ERROR_TOPICS = ("errors/ground_truth", "errors/predicted", "errors/measured")


@dataclass
class DemoSeries:
    """Time series decoded from the demo's bag."""

    components: list[str]
    units: dict[str, str]
    t_true: np.ndarray
    true: dict[str, np.ndarray]
    t_pred: np.ndarray
    predicted: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    probe_times_s: list[float]
    t_applied: np.ndarray                 # stamps of the offsets messages
    applied: dict[str, np.ndarray]        # compensation the CNC held, per component (kinematic mode)
    status: dict[str, Any]
    phases: list[tuple[float, int]]
    limit_hits: int
    offsets_published: int


@dataclass
class _Rows:
    """Per-stamp rows gathered while reading the bag, before they become arrays."""

    true: dict[float, dict[str, float]] = field(default_factory=dict)
    pred: dict[float, tuple[dict[str, float], dict[str, float]]] = field(default_factory=dict)
    applied: dict[float, dict[str, float]] = field(default_factory=dict)
    probes: list[float] = field(default_factory=list)
    status: Any = None                    # the last ModelStatus
    phases: list[tuple[float, int]] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)
    components: list[str] = field(default_factory=list)
    limit_hits: int = 0
    n_offsets: int = 0


def _stamp_s(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _topic_name(topic: str) -> str:
    """The topic without its namespace (``errors/...`` keeps its two last parts)."""
    parts = topic.rsplit("/", 2)
    return "/".join(parts[-2:]) if topic.endswith(_ERROR_TOPICS) else parts[-1]


def _add_errors(rows: _Rows, name: str, data: bytes) -> None:
    msg = deserialize_message(data, ThermalErrors)
    t = _stamp_s(msg)
    vals = dict(zip(msg.component_names, msg.values))
    if name == "errors/ground_truth":
        rows.true[t] = vals
        for c, u in zip(msg.component_names, msg.units):
            rows.units[c] = "um/m" if u == ThermalErrors.UNIT_UM_PER_M else "um"
            if c not in rows.components:
                rows.components.append(c)
    elif name == "errors/predicted":
        rows.pred[t] = (vals, dict(zip(msg.component_names, msg.uncertainties)))
    else:
        rows.probes.append(t)


def _add_status(rows: _Rows, data: bytes) -> None:
    status = deserialize_message(data, ModelStatus)
    rows.status = status
    if not rows.phases or rows.phases[-1][1] != status.phase:
        rows.phases.append((_stamp_s(status), status.phase))


def _add_offsets(rows: _Rows, data: bytes) -> None:
    msg = deserialize_message(data, AxisOffsets)
    rows.n_offsets += 1
    rows.applied[_stamp_s(msg)] = {a: (v if msg.compensation_enabled else 0.0)
                                   for a, v in zip(msg.axis_names, msg.applied_offsets_um)}
    rows.limit_hits += int(any(msg.limits_hit))


def read_series(bag_path: pathlib.Path) -> DemoSeries:
    """Decode ground truth, predictions, measurements, status and offsets from the demo bag."""
    contents = read_bag(bag_path)
    if contents.damage:
        print(f"warning: bag damaged: {contents.damage}", file=sys.stderr)
    rows = _Rows()
    for m in contents.messages:
        name = _topic_name(m.topic)
        if name in _ERROR_TOPICS:
            _add_errors(rows, name, m.data)
        elif name == "model_status":
            _add_status(rows, m.data)
        elif name == "offsets":
            _add_offsets(rows, m.data)
    if not rows.true:
        raise DemoError(f"{bag_path}: no ground-truth errors recorded")
    return _series(rows)


def _series(rows: _Rows) -> DemoSeries:
    components = rows.components
    tt = np.array(sorted(rows.true))
    tp = np.array(sorted(rows.pred))
    true = {c: np.array([rows.true[t].get(c, math.nan) for t in tt]) for c in components}
    pred = {c: np.array([rows.pred[t][0].get(c, math.nan) for t in tp]) for c in components}
    std = {c: np.array([rows.pred[t][1].get(c, math.nan) for t in tp]) for c in components}
    st = {}
    status = rows.status
    if status is not None:
        st = {"phase": int(status.phase), "probing_cycles": int(status.probing_cycles),
              "failed_probing_cycles": int(status.failed_probing_cycles),
              "no_good_phases": int(status.no_good_phases), "parameter_updates": int(status.parameter_updates),
              "q_prod_pct": float(status.q_prod_pct), "model_kind": status.model_kind}
    ta = np.array(sorted(rows.applied))
    applied = {c: np.array([rows.applied[t].get(c, math.nan) for t in ta]) for c in components}
    if not any(np.isfinite(v).any() for v in applied.values()):
        applied = {}   # axis-offset mode: no per-component record of what the CNC held
    return DemoSeries(components, rows.units, tt, true, tp, pred, std, sorted(set(rows.probes)), ta, applied,
                      st, rows.phases, rows.limit_hits, rows.n_offsets)
