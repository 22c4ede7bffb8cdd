"""The twin backend's touch-probe client does not depend on the host node's executor.

rclpy's MultiThreadedExecutor, which runs probe_cycle's action goal, re-yields an in-progress task
before it looks at its wait set, so a service response waiting there was taken only at a lucky
moment: probing cycles stalled for 6-24 s of wall time. The backend's client therefore lives on a
private node with its own executor thread. Shown here in the strongest form: the host node is
never spun at all, and the move is still answered (with the old client it waited for ever).
"""
from __future__ import annotations

import sys
import threading
import pathlib

import pytest

import rclpy  # noqa: E402  (a hard dependency: setup.sh installs it)
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from probe_cycle.cycle_plan import TouchMove  # noqa: E402
from probe_cycle.twin_backend import TwinProbeBackend  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from touch_probe_provider import TouchProbeProvider  # noqa: E402


@pytest.mark.ros
def test_a_move_is_answered_while_the_host_node_is_never_spun(ros_context):
    ns = "/touch_client_private"
    host = rclpy.create_node("probe_cycle", namespace=ns, context=ros_context)   # not spun by anyone
    provider = TouchProbeProvider(context=ros_context, namespace=ns)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(provider)
    spinner = threading.Thread(target=ex.spin, daemon=True)
    spinner.start()
    backend = TwinProbeBackend(host, call_timeout_s=60.0, service_wait_s=60.0)
    try:
        assert backend.client.service_name == f"{ns}/twin/touch_probe"
        t0 = provider.t
        reply = backend.touch(TouchMove(artefact=0, c_axis_deg=0.0, b_axis_deg=0.0,
                                        start_mm=(0.0, 0.0, 50.0), direction=(0.0, 0.0, -1.0),
                                        max_travel_mm=60.0, duration_s=2.0, group=0, stage="test"))
        assert provider.requests == 1
        assert reply.stamp_s == pytest.approx(t0 + 2.0)      # the provider's clock after the move
    finally:
        backend.close()
        ex.shutdown()
        spinner.join(timeout=10.0)
        host.destroy_node()
        provider.destroy_node()
