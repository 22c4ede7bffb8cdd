"""Repair a bag cut by kill -9 so that every standard reader (``rosbags``, ``ros2 bag``) opens it.

A recorder killed between flushes leaves an MCAP file without summary and footer ("File end
magic is invalid" in rosbags). :func:`repair_bag` reads what is intact with our tolerant
reader (:mod:`bag_reader`), writes it into a complete bag of the same name (same topics, QoS,
log times, in recorded order) and keeps the damaged original beside it as ``BAG.damaged``:
nothing is deleted. An intact bag is left alone. No rclpy here.
"""
from __future__ import annotations

import os
import pathlib
import shutil
import tempfile
from dataclasses import dataclass

from thermal_comp_common.bags.reader import BagReadError, read_bag
from thermal_comp_common.bags.writer import BagWriter, TopicInfo


@dataclass(frozen=True)
class RepairResult:
    path: pathlib.Path
    messages: int                  # messages in the repaired (or intact) bag
    damage: str | None             # what was wrong; None: the bag was intact, nothing written
    kept_as: pathlib.Path | None   # where the damaged original was moved


def repair_bag(path: str | os.PathLike) -> RepairResult:
    """Rewrite a damaged bag folder in place (original kept as ``<path>.damaged``).

    Raises :class:`BagReadError` for a path that is no bag, and ``FileExistsError`` when
    ``<path>.damaged`` exists already (an earlier repair).
    """
    path = pathlib.Path(path)
    if not path.is_dir():
        raise BagReadError(f"{path}: not a bag folder (metadata.yaml + .mcap)")
    contents = read_bag(path)
    if contents.damage is None:
        return RepairResult(path, len(contents.messages), None, None)
    kept = path.with_name(path.name + ".damaged")
    if kept.exists():
        raise FileExistsError(f"{kept}: exists already (an earlier repair?); move it away first")
    topics = [TopicInfo(t.name, t.type, list(t.qos) or None) if t.qos else TopicInfo(t.name, t.type)
              for t in contents.topics.values()]
    work = pathlib.Path(tempfile.mkdtemp(prefix=f".{path.name}.repair-", dir=path.parent))
    try:
        fixed = work / path.name
        with BagWriter(fixed, topics, custom_data={"repaired_from": contents.damage}) as w:
            for m in sorted(contents.messages, key=lambda m: m.log_time_ns):   # recorded order
                w.write(m.topic, m.log_time_ns, m.data)
        path.rename(kept)
        fixed.rename(path)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return RepairResult(path, len(contents.messages), contents.damage, kept)
