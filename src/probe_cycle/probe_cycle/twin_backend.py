"""Twin backend: probing moves served by machine_sim's ``twin/touch_probe`` service.

Each request carries the move and its ``duration_s``. machine_sim advances the twin by
that much simulated time, with the machine idle and the currently applied offsets, and
answers from the true geometry at that instant (thermal_twin.machine.artefact_geometry). So the
cycle's 95 s are spent in simulated time, and the reply's stamp is the simulated instant
of the trigger.

Calls block the calling thread. The client lives on a private node spun by its own
single-threaded executor thread: rclpy's MultiThreadedExecutor, which runs the node's action
goal, keeps re-yielding an in-progress task before it looks at its wait set, so a service
response waiting there was taken only at a lucky moment (probing cycles stalled for 6-24 s
of wall time with every process idle). A service that is missing, or that gives no
answer within ``call_timeout_s`` of wall time, raises ``ProbeBackendError``; so does
:meth:`TwinProbeBackend.stop` (from another thread, at once): a node told to stop while
machine_sim is already gone must not sit out the timeout (the launcher's SIGKILL came first).
"""
from __future__ import annotations

import threading
import time

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from thermal_comp_common.runtime.node_runtime import SERVICE_TOUCH_PROBE, stamp_to_s
from thermal_comp_msgs.srv import TouchProbe

from probe_cycle.cycle_plan import TouchMove
from probe_cycle.probe_backend import ProbeBackend, ProbeBackendError, TouchReply


class TwinProbeBackend(ProbeBackend):
    name = "twin"

    def __init__(self, node: Node, call_timeout_s: float = 30.0,
                 service_wait_s: float = 10.0, service_name: str = SERVICE_TOUCH_PROBE):
        self.node = node
        self.call_timeout_s = float(call_timeout_s)
        self.service_wait_s = float(service_wait_s)
        # the node's own remappings are global arguments (__node:=...): the private node takes
        # none, its namespace is the node's, so the service name resolves as it would there
        self._client_node = rclpy.create_node(f"{node.get_name()}_touch_client", namespace=node.get_namespace(),
                                              context=node.context, use_global_arguments=False)
        self.client = self._client_node.create_client(TouchProbe, service_name)
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self._client_node)
        self._spinner = threading.Thread(target=self._spin, name="touch-probe-client", daemon=True)
        self._spinner.start()
        self._stopped = threading.Event()
        self._wake: threading.Event | None = None     # the wait of the move in progress

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:           # context shut down under it (the node's stop): nothing to answer
            pass

    def stop(self) -> None:
        """End the move in progress (its ``touch`` raises at once) and refuse further moves."""
        self._stopped.set()
        wake = self._wake
        if wake is not None:
            wake.set()

    def _check_stopped(self) -> None:
        if self._stopped.is_set():
            raise ProbeBackendError("stopped: the probe_cycle node is shutting down")

    def _wait_for_service(self) -> None:
        """rclpy's wait_for_service sleeps through a stop; this one polls and listens."""
        end = time.monotonic() + self.service_wait_s
        while not self.client.service_is_ready():
            self._check_stopped()
            if time.monotonic() >= end:
                raise ProbeBackendError(f"service '{self.client.service_name}' is not available "
                                        f"(waited {self.service_wait_s:g} s)")
            self._stopped.wait(min(0.05, max(0.0, end - time.monotonic())))

    def touch(self, move: TouchMove) -> TouchReply:
        self._check_stopped()
        self._wait_for_service()
        req = TouchProbe.Request()
        req.artefact = int(move.artefact)
        req.c_axis_deg = float(move.c_axis_deg)
        req.b_axis_deg = float(move.b_axis_deg)
        req.start_mm = [float(v) for v in move.start_mm]
        req.direction = [float(v) for v in move.direction]
        req.max_travel_mm = float(move.max_travel_mm)
        req.duration_s = float(move.duration_s)
        done = self._wake = threading.Event()
        try:
            self._check_stopped()       # a stop() between the check above and the line before
            future = self.client.call_async(req)
            future.add_done_callback(lambda _f: done.set())
            answered = done.wait(self.call_timeout_s) and future.done()
        finally:
            self._wake = None
        if not answered:
            self.client.remove_pending_request(future)
            self._check_stopped()
            raise ProbeBackendError(f"no answer from '{self.client.service_name}' within "
                                    f"{self.call_timeout_s:g} s")
        if future.exception() is not None:
            raise ProbeBackendError(f"'{self.client.service_name}' failed: {future.exception()}")
        res = future.result()
        return TouchReply(bool(res.triggered), np.asarray(res.trigger_position_mm, dtype=float),
                          stamp_to_s(res.stamp), res.message)

    def close(self) -> None:
        self.stop()
        self._executor.shutdown(timeout_sec=1.0)
        self._spinner.join(timeout=2.0)
        self._client_node.destroy_client(self.client)
        self._client_node.destroy_node()
