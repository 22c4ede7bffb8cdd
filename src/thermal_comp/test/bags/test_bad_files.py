"""One line for every bad file, NaN for a failed reading, existing outputs refused unless --force,
and exit codes exactly as each --help states (import-csv, view, play)."""
from __future__ import annotations

import math
import subprocess
import sys

import pytest

from thermal_comp.bags import import_csv_cli

from thermal_comp.bags import play_cli

from thermal_comp.view import cli as view_cli
from thermal_comp_common.bags.reader import BagReadError, read_bag
from thermal_comp_common.bags.msg_definitions import typestore
from thermal_comp_common.recording_csv import RecordingError, read_recording_csv


def _one_line(err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("content, what", [
    (b"time_s,a_c\n0,20.0\n60,\xff\xfe\n", "line 3: not UTF-8 text (byte 0xff)"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "not UTF-8 text"),
    (b"time_s,a_c\n0,2\x000\n", "line 2: a NUL byte"),
])
def test_bad_csv_is_one_line_naming_the_file(tmp_path, capsys, content, what):
    csv = tmp_path / "bad.csv"
    csv.write_bytes(content)
    with pytest.raises(RecordingError, match="bad.csv"):
        read_recording_csv(csv)
    assert import_csv_cli.main([str(csv), str(tmp_path / "out"), "--no-progress"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "bad.csv" in line and what in line
    assert not (tmp_path / "out").exists()


def test_failed_reading_is_stored_as_nan_not_inf(tmp_path, capsys):
    csv = tmp_path / "rec.csv"
    csv.write_text("time_s,a_c,b_c\n0,20.0,inf\n60,-inf,21.0\n120,nan,22.0\n")
    out = tmp_path / "bag"
    assert import_csv_cli.main([str(csv), str(out), "--no-progress"]) == 0
    store = typestore()
    msgs = [store.deserialize_cdr(m.data, m.type) for m in read_bag(out).messages
            if m.topic == "/temperatures"]
    values = [list(m.temperatures_degc) for m in msgs]
    status = [list(m.status) for m in msgs]
    assert not any(math.isinf(v) for row in values for v in row)
    assert math.isnan(values[0][1]) and math.isnan(values[1][0]) and math.isnan(values[2][0])
    assert values[0][0] == 20.0 and values[2][1] == 22.0
    assert status == [[0, 3], [3, 0], [3, 0]]


def test_import_csv_refuses_an_existing_output_unless_forced(tmp_path, capsys):
    csv = tmp_path / "rec.csv"
    csv.write_text("time_s,a_c\n0,20.0\n60,21.0\n")
    out = tmp_path / "bag"
    assert import_csv_cli.main([str(csv), str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert import_csv_cli.main([str(csv), str(out), "--no-progress"]) == 2
    assert "exists already" in _one_line(capsys.readouterr().err)
    assert import_csv_cli.main([str(csv), str(out), "--no-progress", "--force"]) == 0
    assert len(read_bag(out).messages) == 2
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "keep.txt").write_text("x")
    assert import_csv_cli.main([str(csv), str(notes), "--no-progress", "--force"]) == 2
    assert "neither a bag nor an empty folder" in _one_line(capsys.readouterr().err)
    assert (notes / "keep.txt").is_file()
    assert "Exit codes: 0" in import_csv_cli.build_parser().format_help().replace("\n", " ")


def test_bad_bags_are_one_clear_error(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(BagReadError, match="not an MCAP file"):
        read_bag(garbage)
    folder = tmp_path / "badmeta"
    folder.mkdir()
    (folder / "metadata.yaml").write_bytes(b"\xff\xfe\x00 not yaml")
    with pytest.raises(BagReadError, match="not UTF-8"):
        read_bag(folder)


def test_view_refuses_an_existing_rrd_and_unreadable_bags_with_2(tmp_path, capsys):
    rrd = tmp_path / "out.rrd"
    rrd.write_bytes(b"precious")
    assert view_cli.main([str(tmp_path / "x.mcap"), "--rrd", str(rrd), "--no-progress"]) == 2
    assert "--force" in _one_line(capsys.readouterr().err)
    assert rrd.read_bytes() == b"precious"
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x00" * 64)
    assert view_cli.main([str(garbage), "--rrd", str(tmp_path / "new.rrd"), "--no-progress"]) == 2
    assert "not an MCAP file" in _one_line(capsys.readouterr().err)
    help_text = " ".join(view_cli.build_parser().format_help().split())
    assert "3 the bag is damaged" in help_text and "2 bad arguments, unreadable bag" in help_text


@pytest.mark.ros
def test_play_exit_codes_match_its_help(tmp_path):
    help_text = " ".join(play_cli.build_parser().format_help().split())
    assert "3 the bag is damaged" in help_text and "2 bad arguments or unreadable bag" in help_text
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(bytes(range(256)) * 8)
    for bag in (garbage, tmp_path / "missing"):
        r = subprocess.run([sys.executable, "-m", "thermal_comp.bags.play_cli", str(bag), "--as-fast-as-possible"],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, r.stderr
        assert "Traceback" not in r.stderr and str(bag.name) in r.stderr
    r = subprocess.run([sys.executable, "-m", "thermal_comp.bags.play_cli", str(garbage), "--rate", "0"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--rate" in r.stderr
