"""Reading rosbag2 MCAP bags for replay, robust to truncation and corruption.

:func:`read_bag` reads a bag folder (``metadata.yaml`` + ``*.mcap``) or a single ``.mcap``
file record by record with the ``mcap`` stream reader, checking chunk CRCs. When the file
is truncated (a recorder killed between flushes leaves no footer) or damaged, reading stops
at the first bad record and :class:`BagContents.damage` says where (file, byte offset, the
time of the last good message, why); everything before it is kept. Nothing raises for a
damaged MCAP body; a bag its recorder closed on a write error (marked incomplete in its
metadata) is damaged too, with the recorder's reason. A missing file or a malformed ``metadata.yaml`` raises
:class:`BagReadError` naming the path and key.

:func:`instants` groups the messages by their own stamp (:attr:`BagMessage.stamp_ns`, the
header stamp when the type starts with one, else the log time), stable, in recorded order
within one instant. The log time is the receive time in bags ``ros2 bag record`` and our
recorder write, so it is not the instant a message belongs to.
the unit the player publishes before it advances ``/clock``; :func:`wall_delay_s` is the
pacing rule of real-time replay. No rclpy here; the node is :mod:`thermal_comp.bags.player_node`.
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass, field
from typing import Iterator

import yaml
from mcap.exceptions import EndOfFile, RecordLengthLimitExceeded
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from thermal_comp_common.bags.writer import INCOMPLETE_KEY, METADATA_FILE, stamp_from_cdr


class BagReadError(ValueError):
    """A bag cannot be opened at all (missing, not a bag, malformed metadata.yaml)."""


@dataclass(frozen=True)
class BagMessage:
    """One serialized message of a bag."""

    topic: str
    type: str            # 'pkg/msg/Type'
    log_time_ns: int     # receive time (rosbag2), or the stamp in bags of older recorders
    data: bytes
    stamp_ns: int = -1   # the message's header stamp; its log time when it has none

    def __post_init__(self) -> None:
        if self.stamp_ns < 0:
            object.__setattr__(self, "stamp_ns", self.log_time_ns)


_STAMP_TYPES = {"std_msgs/Header", "Header", "std_msgs/msg/Header", "builtin_interfaces/Time",
                "builtin_interfaces/msg/Time", "time"}


def schema_starts_with_stamp(schema_text: str) -> bool:
    """True when the first field of a ros2msg schema is a Header or a Time."""
    for line in schema_text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or line.startswith("="):
            continue
        if "=" in line:
            continue   # a constant: TYPE NAME = VALUE
        return line.split()[0] in _STAMP_TYPES
    return False


@dataclass
class TopicSpec:
    name: str
    type: str
    qos: list[dict] = field(default_factory=list)
    type_hash: str = ""
    message_count: int | None = None   # as metadata.yaml states it (None without metadata)


@dataclass
class BagContents:
    """What could be read from a bag; ``damage`` is None for an intact bag."""

    path: pathlib.Path
    topics: dict[str, TopicSpec]
    messages: list[BagMessage]
    schemas: dict[str, str]            # type -> schema text
    damage: str | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def start_ns(self) -> int | None:
        return self.messages[0].stamp_ns if self.messages else None

    @property
    def end_ns(self) -> int | None:
        return self.messages[-1].stamp_ns if self.messages else None

    def duration_s(self) -> float:
        return 0.0 if not self.messages else (self.end_ns - self.start_ns) * 1e-9


def _key(data: dict, path: list[str], where: str):
    node = data
    for i, k in enumerate(path):
        if not isinstance(node, dict) or k not in node:
            raise BagReadError(f"{where}: missing key '{'.'.join(path[:i + 1])}'")
        node = node[k]
    return node


def incomplete_mark(folder: pathlib.Path) -> str:
    """Why a recorder closed the bag on a write error (its metadata's ``custom_data``), else ""."""
    try:
        info = yaml.safe_load((folder / METADATA_FILE).read_text())["rosbag2_bagfile_information"]
        return str((info.get("custom_data") or {}).get(INCOMPLETE_KEY, ""))
    except (OSError, ValueError, yaml.YAMLError, TypeError, KeyError, AttributeError):
        return ""      # no readable metadata: read_metadata names what is wrong


def read_metadata(folder: pathlib.Path) -> tuple[list[str], dict[str, TopicSpec]]:
    """(relative MCAP file paths, topics) from a bag folder's metadata.yaml."""
    where = str(folder / METADATA_FILE)
    try:
        data = yaml.safe_load((folder / METADATA_FILE).read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise BagReadError(f"{where}: not UTF-8 text (byte {exc.start}); not a bag's metadata") from None
    except yaml.YAMLError as exc:
        raise BagReadError(f"{where}: not valid YAML: {exc}") from None
    info = _key(data, ["rosbag2_bagfile_information"], where)
    storage = _key(info, ["storage_identifier"], where)
    if storage != "mcap":
        raise BagReadError(f"{where}: storage_identifier {storage!r} is not supported (only 'mcap')")
    files = _key(info, ["relative_file_paths"], where)
    if not isinstance(files, list) or not files:
        raise BagReadError(f"{where}: relative_file_paths {files!r} is not a non-empty list")
    if info.get("compression_mode"):
        raise BagReadError(f"{where}: compression_mode {info['compression_mode']!r} is not "
                           f"supported (bags compress chunks inside the MCAP file)")
    topics: dict[str, TopicSpec] = {}
    for i, entry in enumerate(_key(info, ["topics_with_message_count"], where) or []):
        tm = _key(entry, ["topic_metadata"], f"{where}: topics_with_message_count[{i}]")
        name = _key(tm, ["name"], f"{where}: topics_with_message_count[{i}].topic_metadata")
        qos = tm.get("offered_qos_profiles") or []
        if isinstance(qos, str):       # metadata version <= 8 stores a YAML string
            qos = yaml.safe_load(qos) or []
        topics[name] = TopicSpec(name=name, type=_key(tm, ["type"], f"{where}: topic {name!r}"),
                                 qos=qos, type_hash=tm.get("type_description_hash", ""),
                                 message_count=entry.get("message_count"))
    return [str(f) for f in files], topics


def _read_mcap(path: pathlib.Path, contents: BagContents) -> None:
    """Append the messages of one MCAP file to ``contents``; stop at the first damage."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    stamped: dict[int, bool] = {}
    size = path.stat().st_size
    good_offset = 0
    last_t: int | None = None
    finished = False

    def take(records) -> None:
        nonlocal last_t
        for rec in records:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
                contents.schemas[rec.name] = rec.data.decode(errors="replace")
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    raise ValueError(f"message refers to unknown channel id {rec.channel_id}")
                if ch.message_encoding != "cdr":
                    raise ValueError(f"channel {ch.topic!r}: message encoding "
                                     f"{ch.message_encoding!r} is not 'cdr'")
                schema = schemas.get(ch.schema_id)
                if schema is None:
                    raise ValueError(f"channel {ch.topic!r}: unknown schema id {ch.schema_id}")
                if schema.id not in stamped:
                    stamped[schema.id] = schema_starts_with_stamp(schema.data.decode(errors="replace"))
                stamp = stamp_from_cdr(rec.data) if stamped[schema.id] else None
                contents.messages.append(BagMessage(ch.topic, schema.name, rec.log_time, rec.data,
                                                    -1 if stamp is None else stamp))
                last_t = rec.log_time
                if ch.topic not in contents.topics:
                    contents.topics[ch.topic] = TopicSpec(ch.topic, schema.name)

    with open(path, "rb") as f:
        reader = StreamReader(f, emit_chunks=True, validate_crcs=True, record_size_limit=size)
        try:
            for rec in reader.records:
                if isinstance(rec, Chunk):
                    n_before = len(contents.messages)
                    try:
                        take(breakup_chunk(rec, validate_crc=True))
                    except Exception:
                        del contents.messages[n_before:]
                        raise
                else:
                    take([rec])
                good_offset = f.tell()
                if isinstance(rec, (DataEnd, Footer)):
                    finished = True
        except Exception as exc:  # any damage: keep what was read, report where it stopped
            if isinstance(exc, EndOfFile) and good_offset == size:
                reason = "the file ends without MCAP footer: the recording was not closed"
            elif isinstance(exc, (EndOfFile, RecordLengthLimitExceeded)):
                reason = ("the record there runs past the end of the file: truncated "
                          "(recording not closed) or corrupt")
            else:
                reason = f"{exc.__class__.__name__}: {exc}" if str(exc) else exc.__class__.__name__
            contents.damage = (f"{path}: stopped at byte {good_offset} of {size} "
                               f"({reason}); {len(contents.messages)} messages kept"
                               + ("" if last_t is None else f", last at t={last_t * 1e-9:.3f} s"))
            return
    if not finished:
        contents.damage = (f"{path}: file ends without MCAP footer at byte {good_offset}; "
                           f"{len(contents.messages)} messages kept")


MCAP_MAGIC = b"\x89MCAP0\r\n"


def _starts_like_mcap(path: pathlib.Path) -> bool:
    """The file begins with the MCAP magic, or with a prefix of it (a file cut very early)."""
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    return MCAP_MAGIC.startswith(head)


def read_bag(path: str | os.PathLike) -> BagContents:
    """Read a bag folder or an ``.mcap`` file; messages sorted stably by their stamp."""
    path = pathlib.Path(path)
    if path.is_dir():
        if (path / METADATA_FILE).is_file():
            files, topics = read_metadata(path)
            warnings: list[str] = []
        else:
            files = sorted(p.name for p in path.glob("*.mcap"))
            if not files:
                raise BagReadError(f"{path}: neither {METADATA_FILE} nor an .mcap file; not a bag")
            topics, warnings = {}, [f"{path}: no {METADATA_FILE}; topics taken from the MCAP file"]
        mcaps = [path / f for f in files]
    elif path.is_file():
        mcaps, topics, warnings = [path], {}, []
    else:
        raise BagReadError(f"{path}: no such bag (folder or .mcap file)")
    contents = BagContents(path=path, topics=topics, messages=[], schemas={}, warnings=warnings)
    for m in mcaps:
        if not m.is_file():
            contents.damage = f"{m}: listed in {METADATA_FILE} but missing"
            break
        _read_mcap(m, contents)
        if contents.damage:
            if not contents.messages and not _starts_like_mcap(m):
                raise BagReadError(f"{m}: not an MCAP file (no MCAP magic at its start)")
            break
    mark = incomplete_mark(path) if path.is_dir() else ""
    if mark:
        contents.damage = (f"{contents.damage}; " if contents.damage else "") + \
            f"{path}: closed by its recorder on a write error, incomplete: {mark}"
    contents.messages.sort(key=lambda msg: msg.stamp_ns)   # stable: recorded order kept
    return contents


def instants(messages: list[BagMessage]) -> Iterator[tuple[int, list[BagMessage]]]:
    """(stamp_ns, messages of that stamp) in order; input must be sorted by stamp."""
    group: list[BagMessage] = []
    for m in messages:
        if group and m.stamp_ns != group[0].stamp_ns:
            yield group[0].stamp_ns, group
            group = []
        group.append(m)
    if group:
        yield group[0].stamp_ns, group


def wall_delay_s(t_ns: int, start_ns: int, rate: float) -> float:
    """Wall-clock seconds after playback start at which bag time ``t_ns`` is due."""
    if not rate > 0:
        raise ValueError(f"rate {rate!r} must be > 0")
    return (t_ns - start_ns) * 1e-9 / rate
