"""A recorded bag as a :class:`~thermal_comp_common.recording_csv.Recording` (no rclpy).

Replay, regression, evaluation and the mismatch finder all read bags through this one
conversion: one row per temperature instant, machine inputs and error components aligned
to it. A bag that ends early (truncated, damaged, or closed incomplete by its recorder on a
write error) is refused, naming where it ends, unless the command was given
``--allow-truncated`` (:mod:`thermal_comp_common.bags.truncation`): a result on half a recording must not
pass for one on the whole.
"""
from __future__ import annotations

import math
import pathlib
from typing import Sequence

import numpy as np

from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.bags.reader import BagContents, read_bag
from thermal_comp_common.bags.truncation import truncated_allowed
from thermal_comp_common.machine_inputs import machine_state_inputs
from thermal_comp_common.recording_csv import Recording, RecordingError, read_recording_csv
from thermal_comp_common.sensor_readings import model_temperatures


class BagRecordingError(ValueError):
    """The bag cannot be turned into a recording; the message names the bag and topic."""


class TruncatedBagError(BagRecordingError):
    """The bag ends early (damage or an incomplete mark) and truncated bags are not allowed."""


#: the fewest rows a recording must hold to be calibrated on, diagnosed or replayed
MIN_RECORDING_ROWS = 30
#: the fewest finite values a channel the work depends on (an error component) must hold
MIN_CHANNEL_VALUES = 8
#: beyond this magnitude a temperature (degC) or error (um, um/m) value is no measurement
MAX_CHANNEL_MAGNITUDE = 1e6


def check_recording(rec: Recording, required: Sequence[str], others: Sequence[str] = (),
                    stop: int | None = None) -> None:
    """Refuse (RecordingError, one line) a recording whose first ``stop`` rows are too few
    (:data:`MIN_RECORDING_ROWS`), whose channels ``required`` + ``others`` hold an infinite value
    or one beyond :data:`MAX_CHANNEL_MAGNITUDE` (NaN is a missing reading and allowed), or whose
    ``required`` channels hold fewer than :data:`MIN_CHANNEL_VALUES` finite values."""
    n = len(rec) if stop is None else min(stop, len(rec))
    if n < MIN_RECORDING_ROWS:
        raise RecordingError(f"recording {rec.source}: {n} rows, need at least {MIN_RECORDING_ROWS}")
    for name in [*required, *others]:
        v = np.asarray(rec.columns[name][:n], dtype=float)
        bad = np.isinf(v) | (np.abs(np.nan_to_num(v)) > MAX_CHANNEL_MAGNITUDE)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise RecordingError(f"recording {rec.source}: column '{name}': row {k + 1} (t = {rec.time_s[k]:g} s): "
                                 f"{v[k]:g} is no measurement (finite, |value| <= {MAX_CHANNEL_MAGNITUDE:g})")
    for name in required:
        finite = int(np.isfinite(np.asarray(rec.columns[name][:n], dtype=float)).sum())
        if finite < MIN_CHANNEL_VALUES:
            raise RecordingError(f"recording {rec.source}: column '{name}': {finite} finite values, "
                                 f"need at least {MIN_CHANNEL_VALUES}")


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
                   errors_topic: str = "errors/ground_truth", sample_period_s: float | None = None) -> Recording:
    """A recording CSV, or a bag folder / ``.mcap`` file turned into the same columns.

    A bag that ends early (``BagContents.damage``) raises :class:`TruncatedBagError` naming
    where it ends, or, when truncated bags are allowed (``--allow-truncated``), is read up to there with a warning
    in ``Recording.warnings``. Raises ``FileNotFoundError`` for a missing path and
    ``ValueError`` (naming the file, column or topic) for content that cannot be read.
    ``sample_period_s``: a CSV without a ``time_s`` column (row i at i x S); refused for a bag,
    which has its own time stamps.
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"recording {str(path)!r}: no such file or folder")
    if path.is_file() and path.suffix.lower() == ".csv":
        return read_recording_csv(path, sample_period_s=sample_period_s)
    if sample_period_s is not None:
        raise RecordingError(f"{path}: a bag has its own time stamps; a sample period "
                             f"({sample_period_s:g} s, --sample-period-s) is only for a CSV without a time_s column")
    contents = read_bag(path)
    try:
        rec = bag_to_recording(contents, temperatures_topic, errors_topic)
    except BagRecordingError as exc:
        if contents.damage:
            raise TruncatedBagError(f"{exc}; the bag is damaged: {contents.damage}") from None
        raise
    if contents.damage:
        t = rec.time_s
        ends = (f"it ends at t = {t[-1]:.0f} s, {(t[-1] - t[0]) / 3600.0:.2f} h after its first "
                f"instant ({t.size} instants)")
        if not truncated_allowed():
            raise TruncatedBagError(f"{path}: the bag ends early, {ends}: {contents.damage}; "
                                    "--allow-truncated uses what is there")
        rec.warnings.append(f"{path}: the bag ends early, read up to there ({ends}): {contents.damage}")
    return rec
