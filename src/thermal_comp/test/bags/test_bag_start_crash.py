"""A recorder that dies while it starts leaves either no bag or one the tools open (the recorder-kill
row once failed on an empty, unclosed ``bag.2`` that rosbags could not read).

The kills land at exact points, not after a sleep: a child process creates a BagWriter whose topic
list SIGKILLs the process itself after the MCAP file was opened and before its header was written,
or right after the writer was made (header written, nothing flushed since). A recorder refused for
a parameter is checked in-process.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.repair import repair_bag
from thermal_comp_common.bags.writer import BagWriter, TopicInfo

TYPE = "thermal_comp_msgs/msg/MachineState"

KILL_WHILE_CREATING = """
    def topics():                 # the MCAP file is open, its header not written yet
        yield TopicInfo("/a", TYPE)
        os.kill(os.getpid(), signal.SIGKILL)
    BagWriter(out, topics())
"""
KILL_AFTER_CREATING = """
    w = BagWriter(out, [TopicInfo("/a", TYPE)])
    os.kill(os.getpid(), signal.SIGKILL)
"""


def _die(out, body: str) -> None:
    code = textwrap.dedent("""
        import os, signal, sys
        from thermal_comp_common.bags.writer import BagWriter, TopicInfo
        out, TYPE = sys.argv[1], sys.argv[2]
    """) + textwrap.dedent(body)
    r = subprocess.run([sys.executable, "-c", code, str(out), TYPE], capture_output=True, text=True, timeout=120)
    assert r.returncode == -signal.SIGKILL, r.stderr


def test_a_kill_while_the_bag_is_created_leaves_no_bag_and_a_restart_records(tmp_path):
    out = tmp_path / "bag"
    _die(out, KILL_WHILE_CREATING)
    assert not out.exists(), sorted(p.name for p in out.iterdir())
    with BagWriter(out, [TopicInfo("/a", TYPE)]) as w:     # the restarted writer takes the name
        w.write("/a", 1, b"\x00\x01\x00\x00" + bytes(8))
    assert len(read_bag(out).messages) == 1


def test_a_kill_right_after_the_bag_is_created_leaves_a_bag_with_its_header(tmp_path):
    from rosbags.rosbag2 import Reader
    out = tmp_path / "bag"
    _die(out, KILL_AFTER_CREATING)
    assert (out / "bag_0.mcap").read_bytes()[:8] == b"\x89MCAP0\r\n"   # the header is on disk
    contents = read_bag(out)                 # opens: zero messages, the missing footer named
    assert contents.messages == [] and "footer" in contents.damage
    fixed = repair_bag(out)
    assert fixed.damage is not None and fixed.messages == 0
    with Reader(out) as r:                   # and the standard reader opens the repaired bag
        assert list(r.messages()) == []


@pytest.mark.ros
def test_a_recorder_refused_for_a_parameter_leaves_no_bag(tmp_path):
    import rclpy
    from thermal_comp.bags.recorder_node import BagRecorderNode
    out = tmp_path / "bag"
    ctx = rclpy.context.Context()
    rclpy.init(args=["rec", "--ros-args", "-p", f"output:={out}", "-p", "lockstep_participant:=true",
                     "-p", "expect_from_start:=['not_recorded']"], context=ctx)
    try:
        with pytest.raises(ValueError, match="expect_from_start"):
            BagRecorderNode(context=ctx)
    finally:
        ctx.try_shutdown()
    assert not out.exists()
