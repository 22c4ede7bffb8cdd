"""A bag cut by kill -9 is refused by the standard rosbags reader; `record --repair` makes it readable
with every flushed message kept, and keeps the damaged original. Receive-time log times and
header stamps: readers key instants by the stamp."""
from __future__ import annotations

import pytest
from rosbags.rosbag2 import Reader

from thermal_comp.bags import record_cli
from thermal_comp_common.bags.reader import instants, read_bag
from thermal_comp_common.bags.repair import repair_bag
from thermal_comp_common.bags.writer import BagWriter, TopicInfo
from thermal_comp_common.bags.msg_definitions import typestore


def _temps_cdr(t_s: int, value: float) -> bytes:
    store = typestore()
    T = store.types["thermal_comp_msgs/msg/TemperatureArray"]
    H = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    msg = T(header=H(stamp=Time(sec=t_s, nanosec=0), frame_id=""), sensor_ids=["a"],
            temperatures_degc=__import__("numpy").array([value]), status=__import__("numpy").array([0], dtype="uint8"))
    return bytes(store.serialize_cdr(msg, "thermal_comp_msgs/msg/TemperatureArray"))


def _killed_bag(path, n_flushed: int, n_lost: int):
    """What a recorder killed with -9 leaves: flushed chunks, an open chunk, no footer.
    Log time = receive time, a little after each stamp (and out of stamp order once)."""
    w = BagWriter(path, [TopicInfo("/temperatures", "thermal_comp_msgs/msg/TemperatureArray")])
    for k in range(n_flushed + n_lost):
        recv = k * 60_000_000_000 + 5_000_000 + (30_000_000 if k == 1 else 0)
        w.write("/temperatures", recv, _temps_cdr(60 * k, 20.0 + k))
        if k == n_flushed - 1:
            w.flush()
    w._stream.close()    # the process dies: the open chunk and the footer never reach the file


def _rosbags_count(path) -> int:
    with Reader(path) as r:
        return sum(1 for _ in r.messages())


def test_killed_bag_is_repaired_for_the_standard_reader(tmp_path):
    bag = tmp_path / "bag"
    _killed_bag(bag, n_flushed=7, n_lost=3)
    with pytest.raises(Exception, match="(?i)magic|footer|invalid"):
        _rosbags_count(bag)
    r = repair_bag(bag)
    assert r.damage is not None and r.messages == 7
    assert r.kept_as == tmp_path / "bag.damaged" and r.kept_as.is_dir()
    assert _rosbags_count(bag) == 7
    contents = read_bag(bag)
    assert contents.damage is None
    # instants are keyed by header stamp, not by the receive time in the log time
    assert [t for t, _ in instants(contents.messages)] == [60_000_000_000 * k for k in range(7)]
    assert all(m.log_time_ns != m.stamp_ns for m in contents.messages)
    # an intact bag is left alone
    again = repair_bag(bag)
    assert again.damage is None and again.messages == 7


def test_record_cli_repair_and_refusals(tmp_path, capsys):
    bag = tmp_path / "bag"
    _killed_bag(bag, n_flushed=4, n_lost=2)
    assert record_cli.main(["--repair", str(bag)]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "repaired, 4 messages kept" in out
    assert _rosbags_count(bag) == 4
    # a second repair of the (now intact) bag: nothing to do
    assert record_cli.main(["--repair", str(bag)]) == 0
    assert "intact" in capsys.readouterr().out
    # not a bag: one line, exit 2 as the help says
    assert record_cli.main(["--repair", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nothing" in err
    # an existing OUT is refused without --force; a non-bag folder even with --force
    assert record_cli.main([str(bag)]) == 2
    assert "--force" in capsys.readouterr().err
    other = tmp_path / "notes"
    other.mkdir()
    (other / "readme.txt").write_text("keep me")
    assert record_cli.main(["--force", str(other)]) == 2
    assert (other / "readme.txt").is_file()
    assert "exit codes" in record_cli.build_parser().format_help().lower()
