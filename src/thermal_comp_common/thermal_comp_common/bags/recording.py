"""A recorded bag as a :class:`~thermal_comp_common.recording_csv.Recording` (no rclpy).

Replay, regression, evaluation and the mismatch finder all read bags through this one
conversion: one row per temperature instant, machine inputs and error components aligned
to it.
"""
from __future__ import annotations

import math
import pathlib

import numpy as np

from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.bags.reader import BagContents, read_bag
from thermal_comp_common.machine_inputs import machine_state_inputs
from thermal_comp_common.recording_csv import Recording, read_recording_csv
from thermal_comp_common.sensor_readings import model_temperatures


class BagRecordingError(ValueError):
    """The bag cannot be turned into a recording; the message names the bag and topic."""


def _topic(contents: BagContents, rel: str) -> str:
    want = "/" + rel.strip("/")
    matches = [t for t in contents.topics if t == want or t.endswith(want)]
    if len(matches) != 1:
        raise BagRecordingError(f"{contents.path}: topic '{rel}': found {matches or 'none'} "
                              f"among {sorted(contents.topics)}")
    return matches[0]


def bag_to_recording(contents: BagContents, temperatures_topic: str = "temperatures",
                     errors_topic: str = "errors/ground_truth") -> Recording:
    """The bag as a :class:`Recording` at the temperature instants.

    Columns: ``<sensor>_c`` (NaN unless status OK and finite, as the node passes them:
    :func:`~thermal_comp_common.sensor_readings.model_temperatures`), machine
    inputs (last machine state at or before the instant), error components at the same
    stamp (``E_*`` as is, others ``<name>_um``; NaN when none was published then). An
    instant published twice (machine_sim re-sends one whose acknowledgements are late) is
    one row: the later message.
    """
    store = msg_definitions.typestore()
    t_topic = _topic(contents, temperatures_topic)
    e_topic = _topic(contents, errors_topic)
    s_topics = [t for t in contents.topics if t.endswith("/machine_state")]
    rows: list[tuple[float, dict[str, float]]] = []
    state: dict[str, float] = {}
    errors_at: dict[int, dict[str, float]] = {}
    for m in contents.messages:
        if m.topic == e_topic:
            msg = store.deserialize_cdr(m.data, m.type)
            errors_at[m.stamp_ns] = {
                (c if c.startswith("E_") else f"{c}_um"): float(v)
                for c, v in zip(msg.component_names, msg.values)}
    for m in contents.messages:
        if m.topic in s_topics:
            state = machine_state_inputs(store.deserialize_cdr(m.data, m.type))
        elif m.topic == t_topic:
            msg = store.deserialize_cdr(m.data, m.type)
            temps, _ = model_temperatures(msg.sensor_ids, msg.temperatures_degc, msg.status)
            row = {f"{sid}_c": v for sid, v in temps.items()}
            row.update(state)
            row.update(errors_at.get(m.stamp_ns, {}))
            t = m.stamp_ns / 1e9
            if rows and rows[-1][0] == t:   # an instant re-sent by machine_sim: one row per instant
                rows[-1] = (t, row)
            else:
                rows.append((t, row))
    if not rows:
        raise BagRecordingError(f"{contents.path}: no messages on {t_topic}")
    names: list[str] = []
    for _, row in rows:
        names += [k for k in row if k not in names]
    cols = {n: np.array([row.get(n, math.nan) for _, row in rows]) for n in names}
    return Recording(np.array([t for t, _ in rows]), cols, source=str(contents.path))


def load_recording(path, temperatures_topic: str = "temperatures",
                   errors_topic: str = "errors/ground_truth") -> Recording:
    """A recording CSV, or a bag folder / ``.mcap`` file turned into the same columns.

    A damaged bag is read up to the damage, with a warning in ``Recording.warnings``.
    Raises ``FileNotFoundError`` for a missing path and ``ValueError`` (naming the file,
    column or topic) for content that cannot be read.
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"recording {str(path)!r}: no such file or folder")
    if path.is_file() and path.suffix.lower() == ".csv":
        return read_recording_csv(path)
    contents = read_bag(path)
    rec = bag_to_recording(contents, temperatures_topic, errors_topic)
    if contents.damage:
        rec.warnings.append(f"{path}: damaged bag, read up to the damage: {contents.damage}")
    return rec
