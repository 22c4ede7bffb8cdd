"""machine_sim's checkpoint (``state_path``): the twin's complete state, written before every
published instant, so a restarted machine_sim goes on where the twin was.

One file, two slots written in turn, each with a sequence number and a CRC: a save
overwrites the older slot in place, and a load takes the newest slot whose CRC holds. A save
cut short (crash, kill -9) therefore leaves the previous instant readable -- the atomicity a
write-and-rename gives, without a rename per instant (on ext4 a rename over an existing file
forces the data out to disk: 4-8 ms per instant, the largest cost of a lock-step instant).
``fsync=True`` adds an fsync per save (survives a power loss too). A slot holds a private
pickle tagged with the node's parameters; a file written by another configuration is refused
with a message naming the differing parameter. The runner's attributes the node builds the
same way from its parameters (machine, time line: ``shared``) are left out of every save and
taken from the loading node's own runner.
Only ever load a checkpoint machine_sim
wrote (pickle executes code from the file). No rclpy here.
"""
from __future__ import annotations

import os
import pathlib
import pickle
import struct
import zlib

#: slot header: magic, format version, sequence number, payload length, CRC-32 of the payload
_HEADER = struct.Struct("<4sIQQI")
_MAGIC = b"TWCK"
#: smallest slot capacity (bytes); a slot grows (the file is rewritten) when a state outgrows it
_MIN_SLOT = 1 << 18


class TwinCheckpoint:
    """Save and load (runner, probe_rng, applied_offsets) for one machine_sim configuration."""

    VERSION = 2

    def __init__(self, path: str, key: dict, fsync: bool = True, shared: dict | None = None):
        self.path = pathlib.Path(path)
        self.key = dict(key)
        self.fsync = bool(fsync)
        self.shared = dict(shared or {})
        self._seq: int | None = None     # sequence number of the newest slot (None: not opened)
        self._slot_bytes = 0

    def save(self, runner, probe_rng, applied_offsets: dict) -> None:
        # the runner without its shared attributes (a persistent_id hook would be asked about
        # every object pickled: slower than pickling them)
        payload = pickle.dumps({"key": self.key, "shared": sorted(self.shared),
                                "runner": _strip(runner, "", self.shared) if self.shared else runner,
                                "probe_rng": probe_rng, "applied_offsets": dict(applied_offsets)},
                               protocol=pickle.HIGHEST_PROTOCOL)
        seq = 0 if self._seq is None else self._seq + 1
        slot = _HEADER.pack(_MAGIC, self.VERSION, seq, len(payload), zlib.crc32(payload)) + payload
        if self._seq is None or len(slot) > self._slot_bytes:
            self._create(slot)
        else:
            fd = os.open(self.path, os.O_WRONLY)
            try:
                os.pwrite(fd, slot, (seq % 2) * self._slot_bytes)
                if self.fsync:
                    os.fsync(fd)
            finally:
                os.close(fd)
        self._seq = seq

    def _create(self, slot: bytes) -> None:
        """A new file holding ``slot`` in slot 0 (written aside, then renamed into place)."""
        self._slot_bytes = max(_MIN_SLOT, 2 * len(slot))
        tmp = self.path.with_name(self.path.name + ".tmp")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            f.write(slot.ljust(2 * self._slot_bytes, b"\0"))
            f.flush()
            if self.fsync:
                os.fsync(f.fileno())
        os.replace(tmp, self.path)
        self._seq = None

    def load(self):
        """(runner, probe_rng, applied_offsets) from the newest intact slot, or None if there is
        no file; ValueError naming ``state_path`` if no slot is intact or the key differs."""
        if not self.path.is_file():
            return None
        data = self.path.read_bytes()
        newest = None
        for offset in (0, len(data) // 2):
            found = _read_slot(data, offset, self.VERSION)
            if found is not None and (newest is None or found[0] > newest[0]):
                newest = found + (offset,)
        if newest is None:
            raise ValueError(f"parameter 'state_path': {str(self.path)!r} is not a readable twin "
                             f"checkpoint (version {self.VERSION}, no intact slot)")
        seq, payload, offset = newest
        try:
            state = pickle.loads(payload)
            runner = state["runner"]
            if state["shared"]:          # rebuilt from the loading node's parameters
                if sorted(self.shared) != state["shared"]:
                    raise KeyError(f"saved without {state['shared']}, loaded with {sorted(self.shared)}")
                runner = _dress(runner, "", self.shared)
        except Exception as exc:  # a damaged checkpoint must not be half-used
            raise ValueError(f"parameter 'state_path': {str(self.path)!r} is not a readable twin "
                             f"checkpoint ({type(exc).__name__}: {exc})") from None
        for k, v in self.key.items():
            if state["key"].get(k) != v:
                raise ValueError(f"parameter 'state_path': {str(self.path)!r} was written with "
                                 f"{k}={state['key'].get(k)!r}, this node has {k}={v!r}")
        # the next save overwrites the other slot in place
        self._seq, self._slot_bytes = seq, len(data) // 2
        if offset != (seq % 2) * self._slot_bytes:   # slots not where this writer puts them
            self._seq = None
        return runner, state["probe_rng"], state["applied_offsets"]


def _read_slot(data: bytes, offset: int, version: int) -> tuple[int, bytes] | None:
    """(sequence number, payload) of the slot at ``offset`` if it is intact, else None."""
    if offset + _HEADER.size > len(data):
        return None
    magic, ver, seq, length, crc = _HEADER.unpack_from(data, offset)
    start = offset + _HEADER.size
    if magic != _MAGIC or ver != version or start + length > len(data):
        return None
    payload = data[start:start + length]
    return (seq, payload) if zlib.crc32(payload) == crc else None


#: attributes (dotted paths) of a ScenarioRunner that its node's parameters rebuild identically:
#: the machine, the time line and its resolved inputs, the thermal network (constant matrices
#: and a cache of step matrices)
_REBUILT = ("machine", "timeline", "_vals", "_t", "stepper.machine", "stepper.net")


def shared_objects(runner) -> dict:
    """The parts of ``runner`` (a ScenarioRunner) that the node's parameters rebuild identically,
    by dotted attribute path: ``shared`` of :class:`TwinCheckpoint`."""
    out = {}
    for path in _REBUILT:
        obj = runner
        for name in path.split("."):
            obj = getattr(obj, name)
        out[path] = obj
    return out


class _Stripped:
    """An object's class and its attributes less the shared ones (nested objects on a shared
    path stripped too): what is pickled in place of the object."""

    def __init__(self, cls, attrs: dict):
        self.cls, self.attrs = cls, attrs


def _strip(obj, prefix: str, shared: dict) -> _Stripped:
    attrs = {}
    for name, value in vars(obj).items():
        path = prefix + name
        if path in shared:
            continue
        attrs[name] = (_strip(value, path + ".", shared)
                       if any(p.startswith(path + ".") for p in shared) else value)
    return _Stripped(type(obj), attrs)


def _dress(stripped: _Stripped, prefix: str, shared: dict):
    obj = stripped.cls.__new__(stripped.cls)
    for name, value in stripped.attrs.items():
        obj.__dict__[name] = _dress(value, prefix + name + ".", shared) if isinstance(value, _Stripped) else value
    for path, value in shared.items():
        if path.startswith(prefix) and "." not in path[len(prefix):]:
            obj.__dict__[path[len(prefix):]] = value
    return obj
