"""Writing genuine rosbag2 bags: a folder with ``metadata.yaml`` and a zstd-chunked MCAP file.

The layout is what ``ros2 bag record -s mcap`` writes in Jazzy (metadata version 9):

- ``OUT/OUT_0.mcap``: profile ``ros2``; one schema per type (encoding ``ros2msg``, the text
  of :func:`thermal_comp_common.bags.msg_definitions.schema_text`); one channel per topic (encoding
  ``cdr``, metadata ``offered_qos_profiles`` and ``topic_type_hash``); messages in chunks
  compressed with zstd; at the end a ``rosbag2`` metadata record, the summary and footer.
- ``OUT/metadata.yaml``: topics with types, RIHS01 type hashes, QoS and message counts.

Crash safety: :meth:`BagWriter.flush` closes the open chunk, writes it to disk (fsync) and
rewrites ``metadata.yaml`` atomically, so a process killed between flushes loses only the
messages of the chunk that was still open. Such a bag has no MCAP footer; the player
(:mod:`thermal_comp_common.bags.reader`) replays it up to the damage and says where it stopped.

Write errors (a full disk, a quota, an I/O error) lose nothing already written: the writer
closes the bag at the end of the last chunk that was on disk (the partial one is cut off), frees
the few kB it held in reserve (:data:`RESERVE_FILE`, removed on a clean close) and marks it
incomplete in ``metadata.yaml`` (``custom_data`` key :data:`INCOMPLETE_KEY`, with the reason;
readers report the bag as damaged then) and raises :class:`BagIOError`, one line.

Message times: the MCAP ``log_time`` is the message's own stamp when its first field is a
``std_msgs/Header`` or ``builtin_interfaces/Time`` (:func:`stamp_from_cdr`) - deterministic
in simulated time - or the receive time otherwise; ``publish_time`` is the receive time.

This is the pure core of the recorder (no rclpy); the node is
:mod:`thermal_comp.bags.recorder_node`.
"""
from __future__ import annotations

import errno
import os
import pathlib
import shutil
import struct
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from typing import Iterable

import yaml
from mcap.writer import CompressionType, Writer

from thermal_comp_common.bags import msg_definitions
METADATA_FILE = "metadata.yaml"
METADATA_VERSION = 9           # rosbag2 in Jazzy
ROS_DISTRO = "jazzy"
#: "infinite" durations as rosbag2 writes them (RMW_DURATION_INFINITE split in sec/nsec)
INFINITE = {"sec": 9223372036, "nsec": 854775807}
DEFAULT_CHUNK_BYTES = 256 * 1024
#: ``custom_data`` key of a bag closed on a write error: why and where it ends
INCOMPLETE_KEY = "incomplete"
#: space held while recording, freed on a write error so that the incomplete mark fits on a full disk
RESERVE_FILE = METADATA_FILE + ".reserve.tmp"
RESERVE_BYTES = 64 * 1024


class BagWriteError(ValueError):
    """The bag cannot be written (existing folder, unknown topic, closed writer...)."""


class BagIOError(BagWriteError):
    """Writing failed (disk full, I/O error); the bag holds what was on disk before, marked
    incomplete. The message is one line naming the bag, the error and what was kept."""


def qos_dict(reliability: str = "reliable", durability: str = "volatile", history: str = "keep_last",
             depth: int = 100) -> dict:
    """One offered QoS profile in the form of rosbag2 metadata version 9."""
    for key, value, allowed in (("reliability", reliability, ("reliable", "best_effort")),
                                ("durability", durability, ("volatile", "transient_local")),
                                ("history", history, ("keep_last", "keep_all"))):
        if value not in allowed:
            raise BagWriteError(f"QoS {key}: {value!r} is not one of {list(allowed)}")
    return {"history": history, "depth": int(depth), "reliability": reliability,
            "durability": durability, "deadline": dict(INFINITE), "lifespan": dict(INFINITE),
            "liveliness": "automatic", "liveliness_lease_duration": dict(INFINITE),
            "avoid_ros_namespace_conventions": False}


@dataclass
class TopicInfo:
    """A topic of the bag: fully resolved name, 'pkg/msg/Type', offered QoS profiles."""

    name: str
    type: str
    qos: list[dict] = field(default_factory=lambda: [qos_dict()])

    def __post_init__(self) -> None:
        if not self.name.startswith("/"):
            raise BagWriteError(f"topic {self.name!r}: a bag stores fully resolved names ('/...')")
        self.type = msg_definitions.normalize_type(self.type)


def stamp_from_cdr(data: bytes | memoryview) -> int | None:
    """Nanoseconds of the leading ``builtin_interfaces/Time`` of a CDR message, else None.

    Valid for types whose first field is a ``std_msgs/Header`` or a ``Time`` (all our types,
    ``rosgraph_msgs/Clock``): after the 4-byte encapsulation header come int32 sec, uint32
    nanosec in the byte order the encapsulation names.
    """
    if len(data) < 12:
        return None
    kind = bytes(data[0:2])
    if kind == b"\x00\x01":
        sec, nsec = struct.unpack_from("<iI", data, 4)
    elif kind == b"\x00\x00":
        sec, nsec = struct.unpack_from(">iI", data, 4)
    else:
        return None
    if nsec >= 1_000_000_000 or sec < 0:
        return None
    return sec * 1_000_000_000 + nsec


def _library() -> str:
    try:
        return f"thermal_comp-{version('thermal_comp')}; mcap-{version('mcap')}"
    except PackageNotFoundError:  # pragma: no cover - editable installs always have metadata
        return "thermal_comp"


def remove_bag_folder(path: str | os.PathLike) -> None:
    """Delete an existing output bag folder (``--force``): only a bag (``metadata.yaml``,
    ``.mcap`` files) or an empty folder, never anything else (BagWriteError naming it)."""
    path = pathlib.Path(path)
    if not path.exists():
        return
    names = {p.name for p in path.iterdir()} if path.is_dir() else None
    if names is None or not all(n == METADATA_FILE or n.endswith((".mcap", ".tmp")) for n in names):
        raise BagWriteError(f"output {str(path)!r} is neither a bag nor an empty folder; "
                            "not replacing it, even with --force")
    shutil.rmtree(path)


def _os_text(exc: OSError) -> str:
    """'No space left on device (ENOSPC)': an OSError in a few words."""
    name = errno.errorcode.get(exc.errno, "") if exc.errno else ""
    return f"{exc.strerror or exc}" + (f" ({name})" if name else "")


def _fsync_dir(path: pathlib.Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class BagWriter:
    """Writes one rosbag2 MCAP bag folder. Use as a context manager or call :meth:`close`."""

    def __init__(self, path: str | os.PathLike, topics: Iterable[TopicInfo] = (),
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES, compression: str = "zstd",
                 custom_data: dict[str, str] | None = None):
        self.path = pathlib.Path(path)
        if self.path.exists():
            raise BagWriteError(f"output {str(self.path)!r} exists already; not overwriting")
        if compression not in ("zstd", "lz4", "none"):
            raise BagWriteError(f"compression {compression!r} is not one of ['zstd', 'lz4', 'none']")
        # Made under a hidden name and renamed once its MCAP header and metadata.yaml are on disk:
        # a crash while creating leaves no half-made bag at ``path`` (a restarted recorder took a
        # zero-byte file for a bag), only that hidden folder.
        final = self.path
        final.parent.mkdir(parents=True, exist_ok=True)
        self.path = final.with_name(f".{final.name}.creating-{os.getpid()}")
        self.path.mkdir(exist_ok=True)    # left by a killed process of the same pid: reused
        self.mcap_name = f"{final.name}_0.mcap"
        try:
            self._stream = open(self.path / self.mcap_name, "wb")
        except OSError as exc:
            raise BagIOError(f"bag {str(final)!r}: cannot create it: {_os_text(exc)}") from None
        self._writer = Writer(self._stream, chunk_size=chunk_bytes,
                              compression={"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                                           "none": CompressionType.NONE}[compression])
        self._writer.start(profile="ros2", library=_library())
        self.custom_data = dict(custom_data or {})
        self.topics: dict[str, TopicInfo] = {}
        self.hashes: dict[str, str] = {}
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.closed = False
        self.incomplete = ""          # why the bag was closed on a write error ("" otherwise)
        self._on_disk = (0, {}, None, None)   # (MCAP bytes, counts, start, end) at the last sync
        for t in topics:
            self.add_topic(t)
        try:
            self._hold_reserve()
            self.sync()              # the MCAP header on disk (schemas and channels go with the first chunk)
            self._write_metadata()
            self.path.rename(final)
        except (OSError, BagIOError) as exc:
            why = self.incomplete or _os_text(exc)
            try:
                self._stream.close()
            except OSError:
                pass
            raise BagIOError(f"bag {str(final)!r}: cannot create it: {why} "
                             f"(the partial folder {str(self.path)!r} is left)") from None
        self.path = final
        _fsync_dir(final.parent)

    # ----------------------------------------------------------------------------------
    def add_topic(self, topic: TopicInfo) -> None:
        """Register a topic (schema and channel); its type must have an installed .msg file."""
        if self.closed:
            raise BagWriteError("bag writer is closed")
        if topic.name in self.topics:
            if self.topics[topic.name].type != topic.type:
                raise BagWriteError(f"topic {topic.name!r}: already recorded as "
                                    f"{self.topics[topic.name].type}, not {topic.type}")
            return
        if topic.type not in self._schemas:
            text = msg_definitions.schema_text(topic.type)
            self._schemas[topic.type] = self._writer.register_schema(
                name=topic.type, encoding="ros2msg", data=text.encode())
            self.hashes[topic.type] = msg_definitions.type_hash(topic.type)
        self._channels[topic.name] = self._writer.register_channel(
            topic=topic.name, message_encoding="cdr", schema_id=self._schemas[topic.type],
            metadata={"offered_qos_profiles": yaml.safe_dump(topic.qos, sort_keys=False),
                      "topic_type_hash": self.hashes[topic.type]})
        self.topics[topic.name] = topic
        self.counts[topic.name] = 0

    def write(self, topic: str, log_time_ns: int, data: bytes | memoryview,
              publish_time_ns: int | None = None) -> None:
        """Append one serialized (CDR) message of a registered topic."""
        if self.closed:
            raise BagWriteError("bag writer is closed")
        if topic not in self._channels:
            raise BagWriteError(f"topic {topic!r} is not registered in bag {str(self.path)!r}")
        if log_time_ns < 0:
            raise BagWriteError(f"topic {topic!r}: negative time {log_time_ns} ns")
        try:      # a full chunk goes to the file here
            self._writer.add_message(self._channels[topic], log_time=int(log_time_ns), data=bytes(data),
                                     publish_time=int(log_time_ns if publish_time_ns is None
                                                      else publish_time_ns),
                                     sequence=self.counts[topic])
        except OSError as exc:
            self._fail(exc, "writing a message")
        self.counts[topic] += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def flush(self) -> None:
        """Close the open chunk, write it to disk and refresh metadata.yaml (crash safety)."""
        if self.closed:
            return
        try:
            self._writer.flush()
            os.fsync(self._stream.fileno())
            self._mark_on_disk()
            self._write_metadata()
        except OSError as exc:
            self._fail(exc, "flushing")

    def sync(self, fsync: bool = True) -> None:
        """Close the open chunk and hand it to the OS, fsynced unless ``fsync`` is False (metadata.yaml
        left for :meth:`flush`): what was written so far survives a kill -9 (with fsync a power
        loss too). Used before a lock-step acknowledgement."""
        if self.closed:
            return
        try:
            self._writer.flush()
            self._stream.flush()
            if fsync:
                os.fsync(self._stream.fileno())
        except OSError as exc:
            self._fail(exc, "syncing")
        self._mark_on_disk()

    def close(self) -> None:
        """Finish the MCAP file (rosbag2 metadata record, summary, footer) and metadata.yaml."""
        if self.closed:
            return
        try:
            self._writer.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(
                self.metadata()["rosbag2_bagfile_information"], sort_keys=False)})
            self._writer.finish()
            self._stream.flush()
            os.fsync(self._stream.fileno())
            self._stream.close()
        except OSError as exc:
            self._fail(exc, "closing")
        self.closed = True
        try:     # the MCAP file is complete; the reserve goes first, its space is metadata.yaml's
            (self.path / RESERVE_FILE).unlink(missing_ok=True)
            self._write_metadata()
        except OSError as exc:
            raise BagIOError(f"bag {str(self.path)!r}: {_os_text(exc)} while writing {METADATA_FILE}; the MCAP "
                             f"file is complete, {METADATA_FILE} is the one of the last flush") from None

    def _hold_reserve(self) -> None:
        with open(self.path / RESERVE_FILE, "wb") as f:
            f.write(bytes(RESERVE_BYTES))      # written zeros take real blocks (no sparse hole)
            f.flush()
            os.fsync(f.fileno())

    def _mark_on_disk(self) -> None:
        """Remember what the file holds now (a record boundary): a write error later cuts back to it."""
        self._on_disk = (self._stream.tell(), dict(self.counts), self.start_ns, self.end_ns)

    def _fail(self, exc: OSError, during: str) -> None:
        """Close the bag at the end of what was on disk at the last sync, mark it incomplete in
        metadata.yaml and raise BagIOError (one line)."""
        self.closed = True
        offset, counts, self.start_ns, self.end_ns = self._on_disk
        self.counts = {t: counts.get(t, 0) for t in self.counts}
        try:
            self._stream.close()    # its buffer may fail to go out again: the cut below drops it
        except OSError:
            pass
        kept = f"{self.message_count} messages kept"
        if self.end_ns is not None:
            kept += f", up to log time {self.end_ns * 1e-9:.3f} s"
        self.incomplete = f"{_os_text(exc)} while {during}; {kept}"
        self.custom_data[INCOMPLETE_KEY] = self.incomplete
        marked = "marked incomplete"
        try:
            (self.path / RESERVE_FILE).unlink(missing_ok=True)
            os.truncate(self.path / self.mcap_name, offset)   # also frees the space of the cut chunk
            self._write_metadata()
        except OSError as again:
            marked = f"not marked incomplete ({_os_text(again)}; readers still see the missing end)"
        raise BagIOError(f"bag {str(self.path)!r}: {self.incomplete}; closed there, {marked}") from None

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ----------------------------------------------------------------------------------
    def metadata(self) -> dict:
        """The rosbag2 metadata (version 9) of what was written so far."""
        start = self.start_ns or 0
        duration = (self.end_ns - self.start_ns) if self.start_ns is not None else 0
        count = self.message_count
        return {"rosbag2_bagfile_information": {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type, "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos,
                                    "type_description_hash": self.hashes[t.type]},
                 "message_count": self.counts[t.name]}
                for t in self.topics.values()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.mcap_name],
            "files": [{"path": self.mcap_name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration},
                       "message_count": count}],
            "custom_data": dict(self.custom_data),
            "ros_distro": ROS_DISTRO,
        }}

    def _write_metadata(self) -> None:
        tmp = self.path / (METADATA_FILE + ".tmp")
        with open(tmp, "w") as f:
            yaml.safe_dump(self.metadata(), f, sort_keys=False)
            f.flush()
            os.fsync(f.fileno())
        tmp.replace(self.path / METADATA_FILE)
