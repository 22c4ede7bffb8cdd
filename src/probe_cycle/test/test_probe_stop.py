"""A probe_cycle node told to stop while a probing move waits for machine_sim ends that wait at
once and exits, instead of sitting out ``touch_timeout_s`` (the shipped cell's probe_cycle needed
the launcher's SIGKILL: machine_sim stopped first and never answered the move in flight).

The never-answering twin is touch_probe_provider.py with ``answer_first``: it leaves every
request after the first N pending for ever, so the blocked state is reached by construction.
"""
from __future__ import annotations

import os
import pathlib
import queue
import signal
import subprocess
import sys
import threading
import time

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)
from rclpy.executors import MultiThreadedExecutor  # noqa: E402

from probe_cycle.cycle_plan import TouchMove  # noqa: E402
from probe_cycle.probe_backend import ProbeBackendError  # noqa: E402
from probe_cycle.twin_backend import TwinProbeBackend  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from touch_probe_provider import TouchProbeProvider, probe_action_client  # noqa: E402

LONG_S = 600.0     # the backend's own timeouts: far beyond any bound the tests wait


def _move() -> TouchMove:
    return TouchMove(artefact=0, c_axis_deg=0.0, b_axis_deg=0.0, start_mm=(0.0, 0.0, 50.0),
                     direction=(0.0, 0.0, -1.0), max_travel_mm=10.0, duration_s=2.0, group=0,
                     stage="test point")


def _touch_in_thread(backend):
    """Run backend.touch in a thread; the queue receives the exception (or the reply)."""
    out: queue.Queue = queue.Queue()

    def run():
        try:
            out.put(backend.touch(_move()))
        except Exception as exc:   # noqa: BLE001 - the test inspects what was raised
            out.put(exc)
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t, out


@pytest.mark.ros
def test_stop_ends_a_move_whose_answer_never_comes(ros_context):
    """Provider answers nothing (answer_first = 0): touch blocks on the pending call; stop()
    makes it raise at once, naming the shutdown, long before its 600 s timeout."""
    from rclpy.parameter import Parameter
    ns = "/probe_stop_unit"
    node = rclpy.create_node("backend_host", namespace=ns, context=ros_context)
    provider = TouchProbeProvider(context=ros_context, namespace=ns,
                                  parameter_overrides=[Parameter("answer_first", value=0)])
    ex = MultiThreadedExecutor(num_threads=3, context=ros_context)
    ex.add_node(node)
    ex.add_node(provider)
    spinner = threading.Thread(target=ex.spin, daemon=True)
    spinner.start()
    backend = TwinProbeBackend(node, call_timeout_s=LONG_S, service_wait_s=LONG_S)
    try:
        t, out = _touch_in_thread(backend)
        # synchronisation: the request reached the provider (it counts before leaving it pending)
        end = time.monotonic() + 60.0
        while provider.requests < 1:
            assert time.monotonic() < end, "the request never reached the provider"
            assert t.is_alive(), out.get()
            time.sleep(0.01)   # polling a counter, not synchronising by sleep
        assert t.is_alive(), "touch returned although the request was never answered"
        backend.stop()
        t.join(timeout=10.0)
        assert not t.is_alive(), "touch still blocked after stop()"
        exc = out.get_nowait()
        assert isinstance(exc, ProbeBackendError) and "shutting down" in str(exc), exc
        with pytest.raises(ProbeBackendError, match="shutting down"):
            backend.touch(_move())           # refused from then on
    finally:
        backend.close()
        ex.shutdown()
        ros_context.try_shutdown()
        spinner.join(timeout=10.0)


@pytest.mark.ros
def test_stop_ends_the_wait_for_a_missing_service(ros_context):
    node = rclpy.create_node("backend_host_2", namespace="/probe_stop_absent", context=ros_context)
    backend = TwinProbeBackend(node, call_timeout_s=LONG_S, service_wait_s=LONG_S)
    try:
        t, out = _touch_in_thread(backend)
        backend.stop()            # before or during the wait: either way touch must end now
        t.join(timeout=10.0)
        assert not t.is_alive(), "touch still waiting for the service after stop()"
        exc = out.get_nowait()
        assert isinstance(exc, ProbeBackendError) and "shutting down" in str(exc), exc
    finally:
        backend.close()
        node.destroy_node()


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_node_exits_on_signal_with_a_cycle_in_flight(ros_domain_id, sig):
    """probe_cycle (touch_timeout_s 600 s) in a cycle whose 4th move is never answered: the
    signal ends the process with code 0 within the launcher's 5 s grace (bound 15 s here for a
    loaded machine; before the fix it took the 600 s timeout), the cycle logged as failed."""
    from thermal_comp_msgs.action import ProbeCycle
    ns = f"/probe_stop_{sig.name.lower()}"
    env = dict(os.environ)
    provider = subprocess.Popen(
        [sys.executable, str(HERE / "touch_probe_provider.py"), "--ros-args", "-r", f"__ns:={ns}",
         "-p", "answer_first:=3"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    server = subprocess.Popen(
        [sys.executable, "-m", "probe_cycle.probe_cycle_node", "--ros-args", "-r", f"__ns:={ns}",
         "-p", "backend:=twin", "-p", f"touch_timeout_s:={LONG_S}", "-p", f"service_wait_s:={LONG_S}"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    provider_lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [provider_lines.put(x) for x in provider.stdout], daemon=True).start()
    end = time.monotonic() + 120.0
    try:
        with probe_action_client(ns, "probe_stop_client", (server, provider)) as (ex, client):
            goal = ProbeCycle.Goal()
            goal.artefact = ProbeCycle.Goal.ARTEFACT_SPHERE
            goal.set_reference = True
            client.send_goal_async(goal)
            # synchronisation: the provider says it left request 4 pending (the server now waits)
            while True:
                ex.spin_once(timeout_sec=0.05)
                try:
                    line = provider_lines.get_nowait()
                except queue.Empty:
                    assert time.monotonic() < end, "the 4th probing move never reached the provider"
                    continue
                if "request 4 left unanswered" in line:
                    break
            assert server.poll() is None
            t0 = time.monotonic()
            server.send_signal(sig)
            try:
                code = server.wait(timeout=15.0)
            except subprocess.TimeoutExpired:
                server.kill()
                pytest.fail(f"probe_cycle did not exit within 15 s of {sig.name}: {server.communicate()[0]}")
            took = time.monotonic() - t0
            out = server.communicate()[0]
            assert code == 0, out
            assert "probe cycle FAILED" in out and "shutting down" in out, out
            print(f"probe_cycle exited {took:.2f} s after {sig.name}")
    finally:
        for p in (server, provider):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
