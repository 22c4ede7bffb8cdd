"""A truncated or corrupt bag is read up to the damage, which is reported; nothing raises."""
import pathlib
import shutil

import numpy as np
import pytest
from mcap.reader import make_reader

from bags_helpers import small_recording_csv
from thermal_comp_common.bags.reader import BagReadError, read_bag
from thermal_comp_common.bags.csv_to_bag import csv_to_bag


@pytest.fixture(scope="module")
def intact(tmp_path_factory) -> pathlib.Path:
    d = tmp_path_factory.mktemp("intact")
    csv = small_recording_csv(d / "rec.csv", rows=120)
    csv_to_bag(csv, d / "bag", chunk_bytes=2048)   # several chunks
    return d / "bag"


def _damaged_copy(intact: pathlib.Path, dst: pathlib.Path, mutate) -> pathlib.Path:
    shutil.copytree(intact, dst)
    f = dst / "bag_0.mcap"
    f.write_bytes(mutate(bytearray(f.read_bytes())))
    return dst


def _is_prefix(short, full) -> bool:
    # damage keeps whole chunks, so the kept messages are the first ones of the bag per topic
    for topic in {m.topic for m in full}:
        a = [m.data for m in short if m.topic == topic]
        b = [m.data for m in full if m.topic == topic]
        if a != b[:len(a)]:
            return False
    return True


def test_intact_bag_has_several_chunks_and_no_damage(intact):
    c = read_bag(intact)
    assert c.damage is None and len(c.messages) == 360
    with open(intact / "bag_0.mcap", "rb") as f:
        assert make_reader(f).get_summary().statistics.chunk_count >= 5


def test_truncation_anywhere_keeps_a_prefix_and_says_where(intact, tmp_path):
    full = read_bag(intact).messages
    size = (intact / "bag_0.mcap").stat().st_size
    kept = []
    for i, cut in enumerate(np.linspace(0, size - 1, 40).astype(int)):
        c = read_bag(_damaged_copy(intact, tmp_path / f"t{i}", lambda b: b[:cut]))
        assert c.damage is not None, cut
        assert "bag_0.mcap: " in c.damage and ("stopped at byte" in c.damage or "footer" in c.damage)
        assert _is_prefix(c.messages, full), cut
        kept.append(len(c.messages))
    assert kept == sorted(kept)               # the more is left, the more is replayed
    assert kept[0] == 0 and kept[-1] == 360   # the summary/footer carry no messages


def test_flipped_bytes_never_raise_and_stop_at_the_damage(intact, tmp_path):
    full = read_bag(intact).messages
    rng = np.random.default_rng(7)
    size = (intact / "bag_0.mcap").stat().st_size
    damaged = 0
    for i in range(30):
        pos = int(rng.integers(0, size))

        def flip(b, pos=pos):
            b[pos] ^= 0xFF
            return b
        c = read_bag(_damaged_copy(intact, tmp_path / f"c{i}", flip))
        assert _is_prefix(c.messages, full) or c.damage is not None
        if c.damage:
            damaged += 1
            assert f"of {size}" in c.damage
    assert damaged > 0


def test_missing_or_malformed_bags_raise_a_clear_error(tmp_path):
    with pytest.raises(BagReadError, match="no such bag"):
        read_bag(tmp_path / "none")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagReadError, match="not a bag"):
        read_bag(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 9\n")
    with pytest.raises(BagReadError, match="missing key 'storage_identifier'"):
        read_bag(tmp_path / "bad")
    (tmp_path / "bad" / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n")
    with pytest.raises(BagReadError, match="'sqlite3' is not supported"):
        read_bag(tmp_path / "bad")


def test_a_file_listed_in_metadata_but_missing_is_reported(intact, tmp_path):
    dst = tmp_path / "nofile"
    shutil.copytree(intact, dst)
    (dst / "bag_0.mcap").unlink()
    c = read_bag(dst)
    assert c.messages == [] and "missing" in c.damage
