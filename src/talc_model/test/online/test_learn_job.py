"""``thermal-comp learn`` in a process of its own: a snapshot of a bag the recorder is still
writing is readable; the job is polled, never waited for; a job that fails is reported with its
last line, one that hangs is killed (its whole process group) after the timeout, one that cannot
start is a failure at once."""
import os
import pathlib
import sys

import pytest

from talc_model.online.learn_job import (JobEnd, JobState, default_learn_command, learn_argv, parse_command,
                                         snapshot_bag, start_job)

FAKE = str(pathlib.Path(__file__).with_name("fake_learn.py"))


def _temps_msg(t_s: float):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Header
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray
    return serialize_message(TemperatureArray(header=Header(stamp=s_to_stamp(t_s)), sensor_ids=["a"],
                                              temperatures_degc=[20.0 + t_s / 1e5], status=[0]))


def test_a_snapshot_of_a_bag_still_being_written_reads_up_to_its_last_closed_chunk(tmp_path):
    from thermal_comp_common.bags.reader import read_bag
    from thermal_comp_common.bags.writer import BagWriter, TopicInfo

    w = BagWriter(tmp_path / "bag", [TopicInfo("/cell/temperatures", "thermal_comp_msgs/msg/TemperatureArray")])
    for k in range(50):
        w.write("/cell/temperatures", int(k * 300e9), _temps_msg(k * 300.0))
    w.flush()                                    # the recorder's periodic chunk close
    w.write("/cell/temperatures", int(50 * 300e9), _temps_msg(50 * 300.0))   # still in the open chunk
    snap = snapshot_bag(tmp_path / "bag", tmp_path / "snap")
    w.close()
    assert [p.name for p in snap.iterdir()] == ["bag_0.mcap"]
    contents = read_bag(snap)          # what learn --allow-truncated reads: up to the last closed chunk
    assert len(contents.messages) == 50 and contents.messages[-1].stamp_ns == int(49 * 300e9)
    assert "without MCAP footer" in contents.damage


def test_snapshot_of_nothing_is_one_line(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"no \.mcap file"):
        snapshot_bag(tmp_path / "empty", tmp_path / "snap")


def _job(tmp_path, mode: str, timeout_s: float = 60.0):
    (tmp_path / "rec").mkdir(exist_ok=True)
    argv = learn_argv([sys.executable, FAKE, "--mode", mode], tmp_path / "rec", "nmv5000", tmp_path / "out", 38.4)
    return start_job(argv, tmp_path, timeout_s, now_s=100.0)


def test_learn_command_line():
    argv = learn_argv(["thermal-comp", "learn"], pathlib.Path("/r"), "nmv5000", pathlib.Path("/o"), 38.4)
    assert argv == ["thermal-comp", "learn", "/r", "--twin", "nmv5000", "--out", "/o", "--train-h", "38.400",
                    "--allow-truncated", "--quiet"]
    argv = learn_argv(["thermal-comp", "learn"], pathlib.Path("/r"), "/u.yaml", pathlib.Path("/o"), 38.4,
                      "/p.json", "/c.yaml")
    assert argv[5:] == ["--out", "/o", "--train-h", "38.400", "--current-prior", "/p.json", "--current-config",
                        "/c.yaml", "--allow-truncated", "--quiet"]
    assert "--current-config" not in learn_argv(["l"], pathlib.Path("/r"), "t", pathlib.Path("/o"), 1.0, "/p.json")
    assert default_learn_command()[-1] == "learn" and default_learn_command()[0].endswith("thermal-comp")
    assert parse_command("python x.py --mode keep") == ["python", "x.py", "--mode", "keep"]


def test_a_finished_and_a_failed_job(tmp_path):
    (tmp_path / "a").mkdir()
    job = _job(tmp_path / "a", "keep")
    job.proc.wait(timeout=60)
    assert job.poll(101.0) == JobEnd(JobState.DONE, "", 1.0)
    (tmp_path / "b").mkdir()
    job = _job(tmp_path / "b", "fail")
    job.proc.wait(timeout=60)
    end = job.poll(102.0)
    assert end.state is JobState.FAILED
    assert end.reason == "learn exited with code 2: thermal-comp learn: a recording without probing results"


def test_a_hanging_job_is_polled_not_waited_for_and_killed_after_its_timeout(tmp_path):
    job = _job(tmp_path, "hang", timeout_s=30.0)
    assert job.poll(129.0) is None                       # still within its time: not waited for
    end = job.poll(131.0)
    assert end.state is JobState.TIMED_OUT and "longer than 30 s: killed" in end.reason
    assert job.proc.returncode is not None
    with pytest.raises(ProcessLookupError):
        os.killpg(job.proc.pid, 0)                       # the whole group is gone


def test_a_command_that_cannot_start_is_a_failure_at_once(tmp_path):
    end = start_job([str(tmp_path / "no-such-thermal-comp"), "learn"], tmp_path, 10.0, 0.0)
    assert isinstance(end, JobEnd) and end.state is JobState.FAILED and "could not start" in end.reason
