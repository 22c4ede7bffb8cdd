"""A full disk loses nothing already written: the bag writer, on ENOSPC, closes the bag at what
was on disk, readable and marked incomplete, and raises one line (BagIOError); readers report
the bag as damaged, with the reason."""
from __future__ import annotations

import builtins
import errno
import os
import pathlib
import struct

import pytest
import yaml

from thermal_comp_common.bags import writer as writer_mod
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.writer import INCOMPLETE_KEY, RESERVE_FILE, BagIOError, BagWriter, TopicInfo

TOPIC = TopicInfo("/cell/temperatures", "thermal_comp_msgs/msg/TemperatureArray")


class _FullDisk:
    """Every file the writer opens lives on a disk of ``capacity`` bytes (under ``root``): a write
    beyond it writes what fits, then raises OSError(ENOSPC), as a real full file system does."""

    def __init__(self, root: pathlib.Path, capacity: int):
        self.root, self.capacity = root, capacity

    def used(self) -> int:
        return sum(p.stat().st_size for p in self.root.rglob("*") if p.is_file())

    def open(self, path, mode="r", *args, **kw):
        disk = self
        binary = "b" in mode
        f = builtins.open(path, mode, *args, **({"buffering": 0} if binary else {}), **kw)

        class File:
            def write(self, data):
                f.flush()
                size = len(data if binary else data.encode())
                free = disk.capacity - disk.used()
                if size > free:
                    if binary and free > 0:
                        f.write(bytes(data)[:free])
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                return f.write(data)

            def __getattr__(self, name):
                return getattr(f, name)

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                f.close()
        return File()


def _message(t_s: int, payload: int = 400) -> bytes:
    # CDR, little endian: a leading stamp (sec, nanosec), then filler bytes
    return b"\x00\x01\x00\x00" + struct.pack("<iI", t_s, 0) + bytes((t_s + k) % 251 for k in range(payload))


def _record_until_full(tmp_path, monkeypatch, capacity: int):
    disk = _FullDisk(tmp_path, capacity)
    monkeypatch.setattr(writer_mod, "open", disk.open, raising=False)
    w = BagWriter(tmp_path / "bag", [TOPIC], chunk_bytes=4096, compression="none")
    flushed = 0
    with pytest.raises(BagIOError) as err:
        for t in range(1, 100_000):
            w.write(TOPIC.name, t * 10**9, _message(t))
            if t % 5 == 0:          # the recorder's flush period
                w.flush()
                flushed = t
    return w, flushed, str(err.value)


def test_a_full_disk_closes_the_bag_readable_and_marked_incomplete(tmp_path, monkeypatch):
    w, flushed, line = _record_until_full(tmp_path, monkeypatch, capacity=200_000)
    assert flushed > 50, flushed
    assert "\n" not in line and "No space left on device (ENOSPC)" in line and "marked incomplete" in line, line
    monkeypatch.undo()
    bag = tmp_path / "bag"
    contents = read_bag(bag)
    kept = len(contents.messages)       # at least all that was flushed before the disk filled
    assert flushed <= kept <= flushed + 5 and f"; {kept} messages kept, up to log time {kept}.000 s" in line, line
    # in order, and nothing half-written
    assert [m.stamp_ns for m in contents.messages] == [t * 10**9 for t in range(1, kept + 1)]
    assert all(m.data == _message(m.stamp_ns // 10**9) for m in contents.messages)
    assert "incomplete" in contents.damage and "ENOSPC" in contents.damage, contents.damage
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == kept
    assert "ENOSPC" in info["custom_data"][INCOMPLETE_KEY]
    assert not (bag / RESERVE_FILE).exists()
    assert w.closed
    w.close()    # closing again is a no-op, not a second error


def test_a_disk_too_full_to_start_refuses_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr(writer_mod, "open", _FullDisk(tmp_path, 1000).open, raising=False)
    with pytest.raises(BagIOError, match=r"cannot create it: No space left on device \(ENOSPC\)"):
        BagWriter(tmp_path / "bag", [TOPIC])
    assert not (tmp_path / "bag").exists()


def test_a_clean_close_leaves_only_the_bag_files(tmp_path):
    with BagWriter(tmp_path / "bag", [TOPIC]) as w:
        w.write(TOPIC.name, 10**9, _message(1))
    assert sorted(p.name for p in (tmp_path / "bag").iterdir()) == ["bag_0.mcap", "metadata.yaml"]
    contents = read_bag(tmp_path / "bag")
    assert contents.damage is None and len(contents.messages) == 1


def test_a_disk_that_fills_while_closing_keeps_what_was_flushed(tmp_path, monkeypatch):
    disk = _FullDisk(tmp_path, 10**9)
    monkeypatch.setattr(writer_mod, "open", disk.open, raising=False)
    w = BagWriter(tmp_path / "bag", [TOPIC], chunk_bytes=1 << 20, compression="none")
    for t in range(1, 11):
        w.write(TOPIC.name, t * 10**9, _message(t))
    w.flush()
    for t in range(11, 15):         # still in the open chunk: the disk sees them only when closing
        w.write(TOPIC.name, t * 10**9, _message(t))
    disk.capacity = disk.used() + 200
    with pytest.raises(BagIOError, match=r"while closing; 10 messages kept, up to log time 10\.000 s; "
                                         r"closed there, marked incomplete"):
        w.close()
    monkeypatch.undo()
    contents = read_bag(tmp_path / "bag")
    assert [m.stamp_ns // 10**9 for m in contents.messages] == list(range(1, 11))
    assert "incomplete" in contents.damage
