"""A cell across two hosts: two network namespaces joined by a veth pair stand in for an edge PC
beside the machine and a recording/monitoring PC; ROS 2's own DDS discovery joins them.

Host A (10.231.0.1) runs the cell (machine_sim + temperature publisher in lock-step) with
``thermal-comp launch``; host B (10.231.0.2) runs ``thermal-comp nodes``, ``thermal-comp echo``,
``thermal-comp record`` and the live rerun view (``thermal-comp view --rrd``). Discovery is the ordinary SUBNET range (multicast on the link), the
same ROS_DOMAIN_ID on both sides. Fast DDS's shared-memory transport is switched off
(``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``): both namespaces share one kernel and one /dev/shm, so
without it the data could bypass the veth link, which two real hosts never can. The bytes counted
on B's end of the link prove the data crossed it. The second test runs ``thermal-comp sweep`` on
host A against a dask scheduler and workers on host B (only the CLI: no import of thermal_eval).
See docs/distributed.md.
"""
from __future__ import annotations

import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

HOURS, STEP_S = 2.0, 300.0
INSTANTS_NS = [round(k * STEP_S * 1e9) for k in range(int(HOURS * 3600 / STEP_S) + 1)]     # 25 instants
TOPICS = ("machine_state", "twin/sensor_readings", "temperatures", "errors/ground_truth")
ADDR_A, ADDR_B = "10.231.0.1", "10.231.0.2"

CELL = """\
cell: mh
domain_id: {domain_id}
use_sim_time: true
nodes:
  - name: machine_sim
    module: thermal_twin.machine_sim_node
    parameters: {{machine: nmv5000, scenario: load-case-A, seed: 0, hours: {hours}, step_s: {step},
                 lockstep_participants: {participants}, shutdown_when_done: true,
                 wait_for_subscribers: {observers}, lockstep_deadline_s: 60.0}}
  - name: sensors
    module: thermal_sensors.temperature_publisher_node
    parameters: {{source: twin, sensor_config: nmv5000, lockstep_participant: true}}
"""

#: Run on host A: wait (with a deadline) until host B's echo subscribes to machine_state, so the
#: echo is matched before the first instant is published (a graph condition, not a sleep).
WAIT_FOR_ECHO = textwrap.dedent("""
    import sys, time, rclpy
    rclpy.init()
    node = rclpy.create_node("mh_probe", namespace="/mh", start_parameter_services=False)
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        subs = node.get_subscriptions_info_by_topic("/mh/machine_state")
        if any(s.node_name.startswith("_thermal_comp_") for s in subs):     # the CLI's (hidden) graph node
            sys.exit(0)
        rclpy.spin_once(node, timeout_sec=0.1)
    sys.exit(1)
""")


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


class TwoHosts:
    """Two network namespaces ``a`` and ``b`` joined by a veth pair, addresses 10.231.0.1/.2."""

    def __init__(self):
        tag = f"tc{os.getpid()}"
        self.a, self.b = f"{tag}a", f"{tag}b"
        self.veth_a, self.veth_b = f"{tag}va", f"{tag}vb"
        self.created: list[str] = []

    def create(self) -> str | None:
        """Set the pair up; None, or why namespaces cannot be created here."""
        if os.geteuid() != 0:
            return "network namespaces need root (ip netns add)"
        if shutil.which("ip") is None:
            return "the 'ip' command (iproute2) is not installed"
        for ns in (self.a, self.b):
            r = _ip("netns", "add", ns)
            if r.returncode != 0:
                return f"ip netns add {ns} failed: {r.stderr.strip()}"
            self.created.append(ns)
        steps = [("link", "add", self.veth_a, "type", "veth", "peer", "name", self.veth_b),
                 ("link", "set", self.veth_a, "netns", self.a), ("link", "set", self.veth_b, "netns", self.b),
                 ("-n", self.a, "addr", "add", f"{ADDR_A}/24", "dev", self.veth_a),
                 ("-n", self.b, "addr", "add", f"{ADDR_B}/24", "dev", self.veth_b),
                 ("-n", self.a, "link", "set", "lo", "up"), ("-n", self.b, "link", "set", "lo", "up"),
                 ("-n", self.a, "link", "set", self.veth_a, "up"), ("-n", self.b, "link", "set", self.veth_b, "up")]
        for step in steps:
            r = _ip(*step)
            if r.returncode != 0:
                return f"ip {' '.join(step)} failed: {r.stderr.strip()}"
        return None

    def rx_bytes_b(self) -> int:
        r = subprocess.run(["ip", "netns", "exec", self.b, "cat", f"/sys/class/net/{self.veth_b}/statistics/rx_bytes"],
                           capture_output=True, text=True, timeout=30, check=True)
        return int(r.stdout)

    def delete(self) -> None:
        for ns in self.created:           # deleting a namespace deletes its end of the veth pair too
            _ip("netns", "delete", ns)


class Proc:
    """A process in a namespace, its output collected line by line."""

    def __init__(self, ns: str, env: dict, *argv: str):
        self.p = subprocess.Popen(["ip", "netns", "exec", ns, *argv], env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        self._cv = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.p.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                self._cv.notify_all()

    def wait_for(self, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        with self._cv:
            while not any(text in line for line in self.lines):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"never printed {text!r}:\n" + "\n".join(self.lines[-40:]))
                self._cv.wait(left)

    def stop(self, sig=signal.SIGINT, timeout: float = 20.0) -> int:
        if self.p.poll() is None:
            os.killpg(self.p.pid, sig)
            try:
                self.p.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.p.pid, signal.SIGKILL)
                self.p.wait()
        self._reader.join(timeout=5)
        return self.p.returncode

    def output(self) -> str:
        with self._cv:
            return "\n".join(self.lines)


def _run(ns: str, env: dict, *argv: str, timeout: float = 90.0) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", "netns", "exec", ns, *argv], env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("recorder_role", ["observer", "participant"])
def test_a_cell_on_one_host_is_recorded_completely_on_another(tmp_path, ros_domain_id, recorder_role):
    """The remote recorder as an observer machine_sim waits for before the first instant, or as a
    lock-step participant that acknowledges every instant across the link."""
    from thermal_comp_common.bags.reader import read_bag
    hosts = TwoHosts()
    procs: list[Proc] = []
    try:
        why = hosts.create()
        if why is not None:
            pytest.skip(f"cannot build two hosts from network namespaces: {why}")
        (tmp_path / "home").mkdir()                 # rerun writes its analytics settings into HOME
        env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET",
                   FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1", HOME=str(tmp_path / "home"))
        env.pop("ROS_STATIC_PEERS", None)
        cli = [sys.executable, "-m", "thermal_comp.cli"]
        cell = tmp_path / "cell.yaml"
        participant = recorder_role == "participant"
        cell.write_text(CELL.format(domain_id=ros_domain_id, hours=HOURS, step=STEP_S,
                                    participants="[sensors, recorder]" if participant else "[sensors]",
                                    observers="[viewer]" if participant else "[recorder, viewer]"))

        launch = Proc(hosts.a, env, *cli, "launch", str(cell), "--run-dir", str(tmp_path / "run"), "--no-restart")
        procs.append(launch)
        # host B sees host A's nodes by discovery alone
        nodes = _run(hosts.b, env, *cli, "nodes", "--expect", "/mh/machine_sim", "--expect", "/mh/sensors",
                     "--wait", "60")
        assert nodes.returncode == 0, nodes.stdout + nodes.stderr
        echo = Proc(hosts.b, env, *cli, "echo", "/mh/machine_state", "-n", str(len(INSTANTS_NS)),
                    "--reliable", "--wait", "60")
        procs.append(echo)
        matched = _run(hosts.a, env, sys.executable, "-c", WAIT_FOR_ECHO)
        assert matched.returncode == 0, "host A never saw host B's echo subscribe: " + matched.stderr
        rx_before = hosts.rx_bytes_b()
        rrd = tmp_path / "view.rrd"
        viewer = Proc(hosts.b, env, *cli, "view", "--rrd", str(rrd), "--ros-args", "-r", "__ns:=/mh",
                      "-r", "__node:=viewer")
        procs.append(viewer)
        bag = tmp_path / "bag"
        # an observer subscribes to the ground truth (what machine_sim waits for) only once it hears
        # a publisher of each topic the cell publishes from its first instant
        recorder = Proc(hosts.b, env, *cli, "record", str(bag), "--ros-args", "-r", "__ns:=/mh",
                        "-r", "__node:=recorder", "-p", f"lockstep_participant:={str(participant).lower()}",
                        "-p", "expect_from_start:=['temperatures']")
        procs.append(recorder)

        launch.wait_for("mh/machine_sim exited with code 0", timeout=120.0)
        assert echo.p.wait(timeout=60) == 0, echo.output()
        assert launch.stop(signal.SIGTERM) == 0, launch.output()
        assert recorder.stop(signal.SIGINT) == 0, recorder.output()
        assert viewer.stop(signal.SIGINT) == 0, viewer.output()
        rx = hosts.rx_bytes_b() - rx_before

        contents = read_bag(bag)
        assert contents.damage is None, contents.damage
        stamps = {rel: sorted(m.stamp_ns for m in contents.messages if m.topic == f"/mh/{rel}") for rel in TOPICS}
        missing = {rel: [t / 1e9 for t in sorted(set(INSTANTS_NS) - set(s))] for rel, s in stamps.items()}
        assert all(not m for m in missing.values()), f"instants (s) missing in host B's bag: {missing}"
        assert all(s == INSTANTS_NS for s in stamps.values()), "duplicated instants in host B's bag"
        payload = sum(len(m.data) for m in contents.messages)
        assert rx > payload, f"only {rx} bytes crossed the link for {payload} bytes of messages"
        # the echo on host B printed every instant of machine_state too
        assert echo.output().count("---") == len(INSTANTS_NS)
        # and the live view wrote a valid .rrd holding the cell's entities
        rerun = [str(pathlib.Path(sys.executable).parent / "rerun"), "rrd"]
        verify = subprocess.run([*rerun, "verify", str(rrd)], env=env, capture_output=True, text=True, timeout=120)
        assert verify.returncode == 0, verify.stderr
        printed = subprocess.run([*rerun, "print", str(rrd)], env=env, capture_output=True, text=True, timeout=120)
        rows: dict[str, int] = {}                  # scalar rows per entity, summed over its chunks
        for m in re.finditer(r"with (\d+) rows .* - (/\S+) - data columns: \[Scalars:scalars", printed.stdout):
            rows[m.group(2)] = rows.get(m.group(2), 0) + int(m.group(1))
        truth = {e: n for e, n in rows.items() if e.startswith("/mh/errors/") and e.endswith("/ground_truth")}
        assert len(truth) == 7 and set(truth.values()) == {len(INSTANTS_NS)}, rows
    finally:
        for p in reversed(procs):
            p.stop(signal.SIGKILL, timeout=5)
        hosts.delete()


def _rows_without_timing(path: pathlib.Path) -> list[dict]:
    import json
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    return sorted(({k: v for k, v in r.items() if k != "seconds"} for r in rows), key=lambda r: r["key"])


def test_a_sweep_on_dask_workers_of_another_host_survives_a_killed_worker(tmp_path):
    """`thermal-comp sweep --engine dask --address` from host A on a scheduler and two workers on
    host B; one worker process is SIGKILLed from outside once the first result is in: the sweep
    ends with the local pool's answers, every row once."""
    import psutil
    hosts = TwoHosts()
    procs: list[Proc] = []
    try:
        why = hosts.create()
        if why is not None:
            pytest.skip(f"cannot build two hosts from network namespaces: {why}")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        cli = [sys.executable, "-m", "thermal_comp.cli"]
        dask = str(pathlib.Path(sys.executable).parent / "dask")
        rec = tmp_path / "rec.csv"
        sim = subprocess.run([*cli, "sim", "--machine", "nmv5000", "--scenario", "load-case-A", "--hours", "12",
                              "--seed", "3", "--csv", str(rec)], capture_output=True, text=True, timeout=300)
        assert sim.returncode == 0, sim.stderr
        sweep = [*cli, "sweep", str(rec), "--limit", "6", "--grid-subset", "cp_length_h=8.5;post_cp_interval_h=1,3,inf",
                 "--no-progress"]
        local = subprocess.run([*sweep, "--out", str(tmp_path / "local"), "--jobs", "2"], capture_output=True,
                               text=True, timeout=600)
        assert local.returncode == 0, local.stderr

        address = f"tcp://{ADDR_B}:8786"
        scheduler = Proc(hosts.b, env, dask, "scheduler", "--host", ADDR_B, "--port", "8786", "--no-dashboard")
        procs.append(scheduler)
        scheduler.wait_for("Scheduler at:", timeout=60.0)
        workers = Proc(hosts.b, env, dask, "worker", address, "--nworkers", "2", "--nthreads", "1",
                       "--host", ADDR_B, "--no-dashboard")
        procs.append(workers)
        out = tmp_path / "remote"
        client = Proc(hosts.a, env, *sweep, "--out", str(out), "--engine", "dask", "--address", address)
        procs.append(client)
        results = out / "results.jsonl"
        deadline = time.monotonic() + 300.0
        while not (results.exists() and results.read_text().count("\n") >= 1):
            assert client.p.poll() is None, "the sweep ended before a worker could be killed:\n" + client.output()
            assert time.monotonic() < deadline, "no result within 300 s:\n" + client.output()
            try:
                client.p.wait(timeout=0.2)                  # wakes at once if the sweep ends
            except subprocess.TimeoutExpired:
                pass
        # the nannies' worker processes (multiprocessing spawn children, not its resource tracker)
        spawned = [c for c in psutil.Process(workers.p.pid).children()
                   if any("spawn_main" in a for a in c.cmdline())]
        assert len(spawned) == 2, [c.cmdline() for c in psutil.Process(workers.p.pid).children()]
        victim = spawned[0].pid
        spawned[0].kill()                                   # one worker process dies mid-sweep
        assert client.p.wait(timeout=600) == 0, client.output()
        assert _rows_without_timing(results) == _rows_without_timing(tmp_path / "local" / "results.jsonl")
        assert results.read_text().count("\n") == 6
        workers.wait_for(f"Worker process {victim} was killed by signal 9", timeout=60.0)
    finally:
        for p in reversed(procs):
            p.stop(signal.SIGKILL, timeout=5)
        hosts.delete()
