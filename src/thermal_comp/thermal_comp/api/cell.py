"""``Cell``: a running machine cell as a Python object, for scripts, notebooks and the command line.

    from thermal_comp.api import Cell
    with Cell.start("config/cells/nmv5000_twin.yaml") as cell:   # or Cell.attach("/nmv5000", 42)
        cell.wait_until_ready(timeout_s=60)
        result = cell.probe(set_reference=True)
        print(cell.model_status().phase, cell.prediction().values)
        cell.tighten_bridge_limits(abs_limit_um=30.0)

Like nav2's simple commander, it hides the plumbing (action client, latched subscriptions,
the parameter service of the bridge) behind blocking calls, and every call has a deadline:
nothing waits forever. Waits are in wall time; the cell may run on simulated time.
"""
from __future__ import annotations

import io
import pathlib
import threading
import time
from typing import Any, Callable, Mapping

from rclpy.action import ActionClient
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from cnc_bridge.bridge_params import RUNTIME_ENVELOPE, loosening
from thermal_comp.api.graph import CellTimeout, GraphSnapshot, GraphView
from thermal_comp.api.results import Errors, ProbeResult, Status
from thermal_comp.cell.config import CellConfig, load_cell, parse_cell
from thermal_comp.cell.launcher import Launcher
from thermal_comp_common.runtime.node_runtime import (ACTION_PROBE_CYCLE, EVENT_QOS, LATCHED_QOS,
                                                     TOPIC_ERRORS_PREDICTED, TOPIC_MODEL_STATUS)
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import ModelStatus, ThermalErrors

#: the bridge's limits a script may change, each only ever tighter (smaller)
BRIDGE_LIMITS = tuple(RUNTIME_ENVELOPE) + ("abs_limit_um_per_m",)


class CellError(RuntimeError):
    """The cell refused or failed what was asked; the message says what and why."""


class _Discard(io.TextIOBase):
    """An output that keeps nothing (the launcher writes every node's log file anyway)."""

    def write(self, text: str) -> int:
        return len(text)


def _cell_config(cell: str | pathlib.Path | Mapping | CellConfig) -> CellConfig:
    if isinstance(cell, CellConfig):
        return cell
    if isinstance(cell, Mapping):
        return parse_cell(dict(cell), source="<cell mapping>")
    return load_cell(cell)


class Cell:
    """A cell to talk to: attached to one that runs, or started (and then stopped) by this object."""

    def __init__(self, namespace: str = "", domain_id: int | None = None, bridge_node: str = "bridge",
                 launcher: Launcher | None = None, expected_nodes: list[str] | None = None):
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.graph = GraphView(domain_id, self.namespace)
        self.node = self.graph.node
        self.bridge_node = bridge_node
        self.launcher = launcher
        self.expected_nodes = list(expected_nodes or [])
        # subscriptions and clients are made on first use: a cell object that only lists the
        # graph (thermal-comp topics) must not add topics of its own to what it lists
        self._latest: dict[str, Any] = {}
        self._counts: dict[str, int] = {}
        self._probe: ActionClient | None = None
        self._params: AsyncParameterClient | None = None
        self._supervisor: threading.Thread | None = None
        self._stop = threading.Event()

    # ------------------------------------------------------------------ start / attach / stop
    @classmethod
    def attach(cls, namespace: str = "", domain_id: int | None = None, bridge_node: str = "bridge",
               nodes: list[str] = ()) -> "Cell":
        """A cell that runs already, in ``namespace`` on ``domain_id`` (None: the environment's);
        ``nodes`` (names in the namespace) are what :meth:`wait_until_ready` waits for."""
        ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
        return cls(namespace, domain_id, bridge_node, expected_nodes=[f"{ns}/{n.strip('/')}" for n in nodes])

    @classmethod
    def start(cls, cell: str | pathlib.Path | Mapping | CellConfig, run_dir: str | pathlib.Path | None = None,
              output=None, bridge_node: str = "bridge") -> "Cell":
        """Launch a cell (file, mapping or CellConfig) as ``thermal-comp launch`` does and attach
        to it; :meth:`stop` stops it. ``output`` takes the nodes' log lines as well (default: only
        the per-node log files in the run folder, ``cell.launcher.run_dir``)."""
        config = _cell_config(cell)
        launcher = Launcher([config], run_dir=run_dir, output=output if output is not None else _Discard())
        launcher.start()
        try:
            self = cls(config.namespace, launcher.domain_id(config), bridge_node, launcher,
                       [f"{config.namespace}/{n.name}" for n in config.nodes])
        except BaseException:
            launcher.stop()
            raise
        self._supervisor = threading.Thread(target=self._supervise, daemon=True, name="cell-supervisor")
        self._supervisor.start()
        return self

    def _supervise(self) -> None:
        """Restart crashed nodes per the cell's policy while this object lives (the launcher's poll)."""
        while not self._stop.wait(0.2):
            if not self.launcher.poll():
                return

    def stop(self) -> None:
        """Stop what :meth:`start` launched (managed nodes deactivated first) and close the node;
        the launcher stays readable (``cell.launcher.run_dir`` holds the nodes' logs)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._supervisor is not None:
            self._supervisor.join(timeout=5.0)
        if self.launcher is not None:
            self.launcher.stop()
        if self._probe is not None:
            self._probe.destroy()
            self._probe = None
        self.graph.close()

    close = stop

    def __enter__(self) -> "Cell":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ graph
    def watch_graph(self, max_wait_s: float = 10.0, settle_s: float = 1.5, **kw) -> GraphSnapshot:
        """Topics and nodes once discovery settled (or at ``max_wait_s``); see GraphView.watch."""
        return self.graph.watch(max_wait_s, settle_s, **kw)

    def wait_until_ready(self, timeout_s: float = 60.0, nodes: list[str] | None = None) -> float:
        """Wait until every node of the cell is in the graph and its managed nodes are active;
        the seconds it took. CellTimeout names what was missing; CellError if a node failed."""
        want = set(nodes if nodes is not None else self.expected_nodes)
        start = time.monotonic()

        def ready() -> bool:
            if self.launcher is not None and self.launcher.lifecycle_failures:
                return True
            managed_up = self.launcher is None or all(
                mp.lifecycle == "active" for mp in self.launcher.processes if mp.node.lifecycle)
            return managed_up and want <= set(self.graph.nodes())

        if not self.graph.spin_until(ready, timeout_s):
            missing = sorted(want - set(self.graph.nodes()))
            logs = f" (node logs in {self.launcher.run_dir})" if self.launcher is not None else ""
            raise CellTimeout(f"cell not ready within {timeout_s:g} s: "
                              + (f"nodes not seen: {', '.join(missing)}" if missing else "managed nodes not active")
                              + logs)
        if self.launcher is not None and self.launcher.lifecycle_failures:
            raise CellError("; ".join(self.launcher.lifecycle_failures))
        return time.monotonic() - start

    # ------------------------------------------------------------------ topics
    def _keep(self, topic: str, msg) -> None:
        self._latest[topic] = msg
        self._counts[topic] += 1

    def _wait_latest(self, topic: str, timeout_s: float, newer: bool):
        if topic not in self._counts:
            self._counts[topic] = 0
            msg_type, qos = {TOPIC_MODEL_STATUS: (ModelStatus, LATCHED_QOS),
                             TOPIC_ERRORS_PREDICTED: (ThermalErrors, EVENT_QOS)}[topic]
            self.node.create_subscription(msg_type, topic, lambda m: self._keep(topic, m), qos)
        before = self._counts[topic]
        if not self.graph.spin_until(lambda: self._counts[topic] > (before if newer else 0), timeout_s):
            raise CellTimeout(f"no {'new ' if newer else ''}message on "
                              f"{self.node.resolve_topic_name(topic)} within {timeout_s:g} s")
        return self._latest[topic]

    def model_status(self, timeout_s: float = 10.0, newer: bool = False) -> Status:
        """The model's latest status (``newer``: wait for one after this call)."""
        return Status.from_msg(self._wait_latest(TOPIC_MODEL_STATUS, timeout_s, newer))

    def prediction(self, timeout_s: float = 10.0, newer: bool = False) -> Errors:
        """The model's latest predicted errors (``newer``: wait for one after this call)."""
        return Errors.from_msg(self._wait_latest(TOPIC_ERRORS_PREDICTED, timeout_s, newer))

    def subscribe(self, topic: str, msg_type, callback: Callable[[Any], None], qos) -> Any:
        """A subscription on this cell's node (relative names in the cell's namespace)."""
        return self.node.create_subscription(msg_type, topic, callback, qos)

    def spin_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Process callbacks until ``done()`` or ``timeout_s``; whether ``done()`` came true."""
        return self.graph.spin_until(done, timeout_s)

    # ------------------------------------------------------------------ probing
    def probe(self, guide_bush: bool = False, set_reference: bool = False, points: int = 0,
              angles: list[float] | tuple = (), cycle_timeout_s: float = 0.0, tool_position: str = "",
              server_wait_s: float = 10.0, deadline_s: float = 600.0, busy_retry_s: float = 0.0,
              on_feedback: Callable[[Any], None] | None = None) -> ProbeResult:
        """Run one probing cycle and return its result (``success`` False: the cycle failed,
        ``message`` says why). CellTimeout if no server answers in ``server_wait_s`` or no result
        comes in ``deadline_s`` (the goal is then cancelled); CellError if the goal is refused
        (the server runs one cycle at a time: a refused goal is sent again every 0.5 s for up
        to ``busy_retry_s``, e.g. while the model's own cycle runs)."""
        goal = probe_goal(guide_bush, set_reference, points, angles, cycle_timeout_s, tool_position)
        if self._probe is None:
            self._probe = ActionClient(self.node, ProbeCycle, ACTION_PROBE_CYCLE)
        if not self.graph.spin_until(self._probe.server_is_ready, server_wait_s):
            raise CellTimeout(f"no '{self.node.resolve_topic_name(ACTION_PROBE_CYCLE)}' action server "
                              f"answered within {server_wait_s:g} s")
        deadline = time.monotonic() + deadline_s
        retry_until = time.monotonic() + max(0.0, busy_retry_s)
        feedback = (lambda m: on_feedback(m.feedback)) if on_feedback else None
        while True:
            send = self._probe.send_goal_async(goal, feedback_callback=feedback)
            if not self.graph.spin_until(send.done, deadline - time.monotonic()):
                raise CellTimeout(f"the probing goal was not answered within {deadline_s:g} s")
            handle = send.result()
            if handle.accepted:
                break
            if time.monotonic() + 0.5 > min(retry_until, deadline):
                raise CellError("probing goal refused by the server (a cycle is already running?)"
                                + (f" for {busy_retry_s:g} s" if busy_retry_s > 0 else ""))
            self.graph.spin_until(lambda: False, 0.5)
        result = handle.get_result_async()
        if not self.graph.spin_until(result.done, deadline - time.monotonic()):
            cancel = handle.cancel_goal_async()
            self.graph.spin_until(cancel.done, 2.0)
            raise CellTimeout(f"no probing result within {deadline_s:g} s; cancel sent")
        return ProbeResult.from_msg(result.result().result)

    # ------------------------------------------------------------------ bridge limits
    def _bridge_params(self) -> AsyncParameterClient:
        if self._params is None:
            self._params = AsyncParameterClient(self.node, self.bridge_node)
        return self._params

    def _call(self, future, what: str, timeout_s: float):
        if not self.graph.spin_until(future.done, timeout_s):
            raise CellTimeout(f"{what}: no answer from {self._bridge_params().remote_node_name} "
                              f"within {timeout_s:g} s")
        return future.result()

    def bridge_limits(self, timeout_s: float = 5.0) -> dict[str, float]:
        """The bridge's run-time limits (``BRIDGE_LIMITS``) as it holds them now."""
        client = self._bridge_params()
        if not self.graph.spin_until(lambda: client.services_are_ready(), timeout_s):
            raise CellTimeout(f"bridge {client.remote_node_name}: parameter services not found "
                              f"within {timeout_s:g} s")
        reply = self._call(client.get_parameters(list(BRIDGE_LIMITS)), "get limits", timeout_s)
        return {n: parameter_value_to_python(v) for n, v in zip(BRIDGE_LIMITS, reply.values)}

    def tighten_bridge_limits(self, timeout_s: float = 5.0, **limits: float) -> dict[str, float]:
        """Set some of the bridge's limits to tighter (smaller) values; the limits after.

        A value that would widen a limit, a name that is not a limit, or a value that is not a
        finite positive number is refused here, before anything is sent (ValueError); the bridge
        checks again and may refuse (CellError with its reason)."""
        current = self.bridge_limits(timeout_s)
        changes = validated_tightening(limits, current)
        client = self._bridge_params()
        reply = self._call(client.set_parameters([Parameter(n, value=v) for n, v in changes.items()]),
                           "set limits", timeout_s)
        refused = [f"{n}: {r.reason}" for n, r in zip(changes, reply.results) if not r.successful]
        if refused:
            raise CellError("bridge refused " + "; ".join(refused))
        return self.bridge_limits(timeout_s)


def validated_tightening(limits: Mapping[str, Any], current: Mapping[str, float]) -> dict[str, float]:
    """``limits`` as floats if each one names a bridge limit and is no wider than ``current``."""
    out: dict[str, float] = {}
    for name, value in limits.items():
        if name not in BRIDGE_LIMITS:
            raise ValueError(f"{name}: not a bridge limit (one of {', '.join(BRIDGE_LIMITS)})")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: {value!r} is not a number") from None
        if not (v > 0.0 and v < float("inf")):
            raise ValueError(f"{name}: {value!r} is not a finite positive number")
        out[name] = v
    if not out:
        raise ValueError("no limit given (names: " + ", ".join(BRIDGE_LIMITS) + ")")
    why = loosening(out, current)
    if why is not None:
        raise ValueError(f"only tighter limits: {why}")
    return out


def probe_goal(guide_bush: bool, set_reference: bool, points: int, angles, cycle_timeout_s: float,
               tool_position: str = "") -> ProbeCycle.Goal:
    """The ProbeCycle goal of these choices (ValueError naming a bad one)."""
    if not (isinstance(points, int) and points >= 0):
        raise ValueError(f"points: {points!r} is not a whole number >= 0")
    angles = [float(a) for a in angles]
    if any(a != a or abs(a) == float("inf") for a in angles):
        raise ValueError(f"angles: {angles} must be finite")
    if not (cycle_timeout_s >= 0.0 and cycle_timeout_s < float("inf")):
        raise ValueError(f"cycle_timeout_s: {cycle_timeout_s!r} is not a finite number >= 0")
    goal = ProbeCycle.Goal()
    goal.artefact = ProbeCycle.Goal.ARTEFACT_GUIDE_BUSH if guide_bush else ProbeCycle.Goal.ARTEFACT_SPHERE
    goal.set_reference = bool(set_reference)
    goal.points_per_indexing = points
    goal.c_angles_deg = angles
    goal.timeout_s = float(cycle_timeout_s)
    goal.tool_position = tool_position
    return goal
