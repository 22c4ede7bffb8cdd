"""A recorder restarted by the launcher after a crash must record again, not refuse its folder."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from thermal_comp_common.bags.reader import read_bag

pytestmark = [pytest.mark.ros]


def _recorder(out) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "thermal_comp.bags.recorder_node", "--ros-args",
                             "-r", "__ns:=/restart_test", "-p", f"output:={out}"],
                            env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_for_line(proc, text, timeout_s=60.0) -> list[str]:
    import selectors
    import time
    lines = []
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sel.select(timeout=0.5):
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if text in line:
                return lines
    raise AssertionError(f"never printed {text!r}:\n{''.join(lines)}")


def test_restarted_recorder_continues_in_a_new_bag_and_keeps_the_old(tmp_path):
    out = tmp_path / "bag"
    first = _recorder(out)
    try:
        _wait_for_line(first, "recording")
    finally:
        first.send_signal(signal.SIGKILL)   # a crash: no clean close
        first.wait(timeout=30)
    assert out.is_dir()
    second = _recorder(out)
    try:
        _wait_for_line(second, "recording continues in")
    finally:
        second.send_signal(signal.SIGINT)
        second.wait(timeout=30)
    assert second.returncode == 0
    assert (tmp_path / "bag.2" / "metadata.yaml").is_file(), "the restarted recorder wrote no bag"
    read_bag(out)                # the crashed bag is left as it was and still opens
    read_bag(tmp_path / "bag.2")


@pytest.mark.slow
def test_lockstep_recorder_loses_no_instant_across_a_kill_and_restart(tmp_path):
    """The recorder as a lock-step participant: machine_sim cannot run ahead of a dead recorder,
    so bag + bag.2 hold every instant of machine_sim's streams; the killed bag is repaired for
    the standard reader."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosbags.rosbag2 import Reader

    from thermal_comp_common.bags.repair import repair_bag
    from thermal_comp_common.runtime.child_processes import stop
    from thermal_comp_common.runtime.node_runtime import EVENT_QOS, TOPIC_SIM_SYNC, stamp_to_s
    from thermal_comp_msgs.msg import SimSync

    ns, hours, step = "/restart_lockstep", 1.0, 60.0
    out = tmp_path / "bag"
    rec_argv = [sys.executable, "-m", "thermal_comp.bags.recorder_node", "--ros-args", "-r", f"__ns:={ns}",
                "-p", f"output:={out}", "-p", "lockstep_participant:=true"]
    sim = subprocess.Popen([sys.executable, "-m", "thermal_twin.machine_sim_node", "--ros-args",
                            "-r", f"__ns:={ns}", "-p", f"hours:={hours}", "-p", f"step_s:={step}",
                            "-p", "lockstep_participants:=['bag_recorder']", "-p", "shutdown_when_done:=true",
                            "-p", "lockstep_deadline_s:=60.0", "-p", "resend_after_s:=0.5"],
                           env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("restart_watch", namespace=ns, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    acked: list[float] = []
    node.create_subscription(SimSync, TOPIC_SIM_SYNC, lambda m: acked.append(stamp_to_s(m.processed_until)),
                             EVENT_QOS)
    first = subprocess.Popen(rec_argv, env=dict(os.environ), stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    second = None
    try:
        end = time.monotonic() + 120
        while (not acked or max(acked) < 1200.0) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert acked and max(acked) >= 1200.0, "the recorder never acknowledged 20 instants"
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
        killed_at = max(acked)
        second = subprocess.Popen(rec_argv, env=dict(os.environ), stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True)
        sim_out = sim.communicate(timeout=180)[0]
        assert sim.returncode == 0, sim_out
    finally:
        for p in (first, second, sim):
            stop(p)
        ex.shutdown()
        node.destroy_node()
        ctx.try_shutdown()
    assert second.returncode == 0
    assert killed_at < hours * 3600.0
    repair_bag(out)     # the killed bag: made readable for the standard reader
    for b in (out, tmp_path / "bag.2"):
        with Reader(b) as r:
            assert sum(1 for _ in r.messages()) > 0
    want = {int(round(k * step)) for k in range(int(hours * 3600 / step) + 1)}
    for topic in ("machine_state", "twin/sensor_readings"):
        got = set()
        for b in (out, tmp_path / "bag.2"):
            got |= {int(round(m.stamp_ns / 1e9)) for m in read_bag(b).messages if m.topic == f"{ns}/{topic}"}
        assert got == want, f"{topic}: missing instants {sorted(want - got)}"
