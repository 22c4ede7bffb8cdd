"""Shared by the view tests: a small bag with data on the simulated clock and health records
(/rosout, /diagnostics) stamped by the wall clock, and reading an .rrd back per timeline."""
from __future__ import annotations

import collections
import pathlib

import numpy as np
from rerun.chunk import RrdReader

from thermal_comp_common.bags import msg_definitions as md
from thermal_comp_common.bags.writer import BagWriter, TopicInfo

WALL0_S = 1_795_808_975          # a wall-clock date (2026)
STEP_S = 300
COMPONENTS = ["E_X0C", "E_Z0T"]


def _stamp(store, t_s: float):
    return store.types["builtin_interfaces/msg/Time"](sec=int(t_s), nanosec=int(round((t_s % 1) * 1e9)))


def health_bag(path: pathlib.Path, instants: int = 12, t0_s: float = 600.0) -> tuple[float, float]:
    """A bag of ``instants`` data instants from ``t0_s`` (simulated s) with a /rosout line and a
    wall-stamped /diagnostics status received after each; (first, last) data stamp in s."""
    s = md.typestore()
    H = s.types["std_msgs/msg/Header"]
    topics = {"/cell1/temperatures": "thermal_comp_msgs/msg/TemperatureArray",
              "/cell1/errors/ground_truth": "thermal_comp_msgs/msg/ThermalErrors",
              "/rosout": "rcl_interfaces/msg/Log", "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
    with BagWriter(path, [TopicInfo(n, t) for n, t in topics.items()]) as w:
        for k in range(instants):
            t = t0_s + STEP_S * k
            wall = WALL0_S + 0.7 * k
            h = H(stamp=_stamp(s, t), frame_id="")
            msgs = {
                "/cell1/temperatures": s.types[topics["/cell1/temperatures"]](
                    header=h, sensor_ids=["spindle"], temperatures_degc=np.array([25.0 + 0.1 * k]),
                    status=np.zeros(1, np.uint8)),
                "/cell1/errors/ground_truth": s.types[topics["/cell1/errors/ground_truth"]](
                    header=h, source=2, model_kind="twin", component_names=COMPONENTS,
                    values=np.array([0.5 * k, -0.3 * k]), units=np.zeros(2, np.uint8),
                    uncertainties=np.full(2, np.nan)),
                "/rosout": s.types[topics["/rosout"]](
                    stamp=_stamp(s, wall), level=20, name="cell1.talc_model", msg=f"step {k}",
                    file="f.py", function="f", line=1),
                "/diagnostics": s.types[topics["/diagnostics"]](
                    header=H(stamp=_stamp(s, wall), frame_id=""),
                    status=[s.types["diagnostic_msgs/msg/DiagnosticStatus"](
                        level=k % 2, name="bridge", message="ok" if k % 2 == 0 else "clamped",
                        hardware_id="cnc", values=[])]),
            }
            for topic, msg in msgs.items():   # received in this order, on the simulated clock
                w.write(topic, int(t * 1e9), bytes(s.serialize_cdr(msg, topics[topic])))
    return t0_s, t0_s + STEP_S * (instants - 1)


def timeline_spans(rrd: pathlib.Path) -> dict[str, dict[str, tuple[float, float]]]:
    """timeline -> entity -> (first, last) instant in s, of every non-static row in the file."""
    spans: dict[str, dict[str, list[float]]] = collections.defaultdict(dict)
    for chunk in RrdReader(rrd).stream():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        for name in chunk.timeline_names:
            ns = [v for v in batch.column(name).cast("int64").to_pylist() if v is not None]
            if not ns:
                continue
            lo, hi = min(ns) * 1e-9, max(ns) * 1e-9
            old = spans[name].get(chunk.entity_path)
            spans[name][chunk.entity_path] = [lo, hi] if old is None else [min(old[0], lo), max(old[1], hi)]
    return {tl: {e: tuple(v) for e, v in ents.items()} for tl, ents in spans.items()}


def blueprint_timeline(rrd: pathlib.Path) -> list[str]:
    """The timeline(s) the file's blueprint sets its time panel to."""
    reader = RrdReader(rrd)
    out = []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                if name.endswith(":timeline") and "TimePanel" in name:
                    out += [v for v in batch.column(name).to_pylist() if v]
    return [v[0] if isinstance(v, list) else v for v in out]
