"""A small stand-in for launch and launch_ros that runs a launch file for real.

launch/launch_ros have no wheels for this venv (docs/launch.md says what was tried), so this
double takes their place for the tests: each class accepts only the keyword arguments of its
Jazzy counterpart; node actions start real processes with the command line launch_ros builds;
launch's events (ProcessStarted, ProcessExited, ChangeState, StateTransition, Shutdown) and
TimerActions are dispatched to the handlers the file registers; and a LifecycleNode talks to its node over the
interfaces launch_ros uses: it turns the node's ``<node>/transition_event`` messages into
StateTransition events and a ChangeState event into a ``<node>/change_state`` call. Respawn
follows launch's rule (the k-th exit is respawned while k <= respawn_max_retries).
"""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
import types

import rclpy
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState as ChangeStateSrv
from rclpy.executors import SingleThreadedExecutor

EXECUTE_PROCESS_KW = {"cmd", "name", "cwd", "env", "additional_env", "shell", "sigterm_timeout",
                      "sigkill_timeout", "emulate_tty", "output", "output_format", "log_cmd",
                      "on_exit", "respawn", "respawn_delay", "respawn_max_retries", "prefix",
                      "cached_output"}
NODE_KW = {"executable", "package", "name", "namespace", "exec_name", "parameters", "remappings",
           "ros_arguments", "arguments"} | (EXECUTE_PROCESS_KW - {"cmd"})


class Action:
    """Keeps its arguments after checking them against the Jazzy signature."""

    allowed: set[str] = set()

    def __init__(self, *args, **kwargs):
        unknown = set(kwargs) - self.allowed
        assert not unknown, f"{type(self).__name__} takes no {sorted(unknown)}"
        self.args, self.kwargs = args, kwargs


def _cls(name, allowed):
    return type(name, (Action,), {"allowed": set(allowed)})


DeclareLaunchArgument = _cls("DeclareLaunchArgument", {"default_value", "description", "choices"})
OpaqueFunction = _cls("OpaqueFunction", {"function", "args", "kwargs"})
class RegisterEventHandler(Action):
    allowed = {"event_handler"}

    def __init__(self, event_handler, **kwargs):   # positional or keyword, as in launch
        super().__init__(event_handler=event_handler, **kwargs)


EmitEvent = _cls("EmitEvent", {"event"})
LogInfo = _cls("LogInfo", {"msg"})
Shutdown = _cls("Shutdown", {"reason"})
IncludeLaunchDescription = _cls("IncludeLaunchDescription", {"launch_arguments"})
PythonLaunchDescriptionSource = _cls("PythonLaunchDescriptionSource", set())
Node = _cls("Node", NODE_KW)
LifecycleNode = _cls("LifecycleNode", NODE_KW)
OnProcessStart = _cls("OnProcessStart", {"target_action", "on_start", "handle_once"})
OnProcessExit = _cls("OnProcessExit", {"target_action", "on_exit", "handle_once"})
OnStateTransition = _cls("OnStateTransition", {"target_lifecycle_node", "transition", "start_state",
                                               "goal_state", "entities", "matcher", "handle_once"})
ChangeState = _cls("ChangeState", {"lifecycle_node_matcher", "transition_id"})
TimerAction = _cls("TimerAction", {"period", "actions", "cancel_on_shutdown"})


class LaunchConfiguration:
    def __init__(self, name, default=None):
        self.name, self.default = name, default

    def perform(self, context):
        if self.name in context.launch_configurations:
            return context.launch_configurations[self.name]
        assert self.default is not None, f"launch configuration {self.name!r} not set"
        return self.default


def matches_action(action):
    return lambda candidate: candidate is action


def modules(share_dir: str = "/opt/share") -> dict[str, types.ModuleType]:
    """The launch / launch_ros / ament_index_python modules a launch file imports."""
    names = ["launch", "launch.actions", "launch.event_handlers", "launch.events", "launch.substitutions",
             "launch.launch_description_sources", "launch_ros", "launch_ros.actions",
             "launch_ros.event_handlers", "launch_ros.events", "launch_ros.events.lifecycle",
             "ament_index_python", "ament_index_python.packages"]
    mods = {n: types.ModuleType(n) for n in names}
    mods["launch"].LaunchDescription = lambda actions: list(actions)
    for n in ("DeclareLaunchArgument", "OpaqueFunction", "RegisterEventHandler", "EmitEvent", "LogInfo",
              "Shutdown", "IncludeLaunchDescription", "TimerAction"):
        setattr(mods["launch.actions"], n, globals()[n])
    mods["launch.event_handlers"].OnProcessStart = OnProcessStart
    mods["launch.event_handlers"].OnProcessExit = OnProcessExit
    mods["launch.events"].matches_action = matches_action
    mods["launch.substitutions"].LaunchConfiguration = LaunchConfiguration
    mods["launch.launch_description_sources"].PythonLaunchDescriptionSource = PythonLaunchDescriptionSource
    mods["launch_ros.actions"].Node = Node
    mods["launch_ros.actions"].LifecycleNode = LifecycleNode
    mods["launch_ros.event_handlers"].OnStateTransition = OnStateTransition
    mods["launch_ros.events.lifecycle"].ChangeState = ChangeState
    mods["ament_index_python.packages"].get_package_share_directory = lambda pkg: f"{share_dir}/{pkg}"
    return mods


class _Proc:
    """A node action's process and its respawn bookkeeping."""

    def __init__(self, action):
        self.action, self.popen, self.exits, self.due = action, None, 0, None
        kw = action.kwargs
        assert kw.get("package") is None, "the double runs nodes given by module (no install here)"
        self.name = f"{kw['namespace']}/{kw['name']}"
        self.cmd = [kw["executable"], *kw.get("arguments", []), "--ros-args", "-r", f"__node:={kw['name']}",
                    "-r", f"__ns:={kw['namespace']}", *(a for p in kw.get("parameters", []) for a in ("--params-file", p))]


class MiniLaunch:
    """Runs a launch description: ``run(description, launch_arguments, until, timeout_s)``."""

    def __init__(self, ros_context):
        self.lines: list[str] = []
        self.events: queue.Queue = queue.Queue()
        self.launch_configurations: dict[str, str] = {}
        self.is_shutdown = False
        self.shutdown_reason: str | None = None
        self.transitions: list[tuple[str, str, str]] = []   # (node, start label, goal label)
        self._handlers: list[Action] = []
        self._timers: list[tuple[float, list]] = []      # (due, actions) of TimerActions
        self._procs: list[_Proc] = []
        self._clients: dict[int, object] = {}
        self._ros = rclpy.create_node("launch_double", context=ros_context)
        self._executor = SingleThreadedExecutor(context=ros_context)
        self._executor.add_node(self._ros)

    # -- actions -------------------------------------------------------------------------
    def visit(self, action) -> None:
        kind = type(action).__name__
        if kind == "DeclareLaunchArgument":
            name = action.args[0]
            if name not in self.launch_configurations:
                assert "default_value" in action.kwargs, f"launch argument {name!r} is required"
                self.launch_configurations[name] = action.kwargs["default_value"]
        elif kind == "OpaqueFunction":
            for a in action.kwargs["function"](self) or []:
                self.visit(a)
        elif kind == "RegisterEventHandler":
            self._handlers.append(action.kwargs["event_handler"])
        elif kind == "EmitEvent":
            self.events.put(("ChangeState", action.kwargs["event"]))
        elif kind == "TimerAction":
            self._timers.append((time.monotonic() + action.kwargs["period"], action.kwargs["actions"]))
        elif kind == "LogInfo":
            self.lines.append(f"[launch] {action.kwargs['msg']}")
        elif kind == "Shutdown":
            self.events.put(("Shutdown", action.kwargs.get("reason", "")))
        elif kind in ("Node", "LifecycleNode"):
            proc = _Proc(action)
            self._procs.append(proc)
            if kind == "LifecycleNode":
                self._ros.create_subscription(TransitionEvent, f"{proc.name}/transition_event",
                                              lambda m, p=proc: self.events.put(("StateTransition", (p, m))), 10)
                self._clients[id(action)] = self._ros.create_client(ChangeStateSrv, f"{proc.name}/change_state")
            self._start(proc)
        else:
            raise AssertionError(f"the double does not run {kind}")

    def _start(self, proc: _Proc) -> None:
        env = {**os.environ, **proc.action.kwargs.get("additional_env", {})}
        proc.popen = subprocess.Popen(proc.cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                      text=True, start_new_session=True)
        threading.Thread(target=self._pump, args=(proc, proc.popen), daemon=True).start()
        self.events.put(("ProcessStarted", proc.action))   # handled after the actions visited with it

    def _pump(self, proc, popen) -> None:
        for line in popen.stdout:
            self.lines.append(f"[{proc.name}] {line.rstrip()}")

    # -- events --------------------------------------------------------------------------
    def _entities(self, result, event) -> None:
        for a in (result(event, self) if callable(result) else result) or []:
            self.visit(a)

    def _dispatch(self, kind: str, action, event) -> None:
        for h in list(self._handlers):
            kw, name = h.kwargs, type(h).__name__
            if kw.get("handle_once") and self._matches(h, kind, action, event):
                self._handlers.remove(h)
            if not self._matches(h, kind, action, event):
                continue
            self._entities(kw.get("on_start", kw.get("on_exit", kw.get("entities"))), event)

    @staticmethod
    def _matches(handler, kind: str, action, event) -> bool:
        kw, name = handler.kwargs, type(handler).__name__
        if name in ("OnProcessStart", "OnProcessExit"):
            return kind == ("ProcessStarted" if name == "OnProcessStart" else "ProcessExited") and \
                kw["target_action"] is action
        return name == "OnStateTransition" and kind == "StateTransition" and \
            kw["target_lifecycle_node"] is action and kw.get("start_state") in (None, event.start_state) and \
            kw.get("goal_state") in (None, event.goal_state)

    def _change_state(self, event) -> None:
        for proc in self._procs:
            client = self._clients.get(id(proc.action))
            if client is None or not event.kwargs["lifecycle_node_matcher"](proc.action):
                continue
            request = ChangeStateSrv.Request()
            request.transition.id = event.kwargs["transition_id"]
            threading.Thread(target=self._call, args=(client, request), daemon=True).start()

    def _call(self, client, request) -> None:   # as launch_ros: wait for the service, then call
        while not self.is_shutdown and not client.wait_for_service(timeout_sec=0.2):
            pass
        if not self.is_shutdown:
            self.lines.append(f"[double] {client.srv_name}: transition {request.transition.id} requested")
            client.call_async(request).add_done_callback(lambda f: self.lines.append(
                f"[double] {client.srv_name}: transition {request.transition.id} answered "
                f"{'success' if f.result() and f.result().success else 'failure'}"))

    def _handle(self, kind, payload) -> None:
        if kind == "ChangeState":
            self._change_state(payload)
        elif kind == "StateTransition":
            proc, msg = payload
            self.transitions.append((proc.name, msg.start_state.label, msg.goal_state.label))
            self._dispatch("StateTransition", proc.action, types.SimpleNamespace(
                start_state=msg.start_state.label, goal_state=msg.goal_state.label))
        elif kind == "ProcessStarted":
            self._dispatch("ProcessStarted", payload, None)
        elif kind == "Shutdown" and not self.is_shutdown:
            self.is_shutdown, self.shutdown_reason = True, payload

    def _poll_processes(self) -> None:
        now = time.monotonic()
        for proc in self._procs:
            if proc.popen is not None and proc.popen.poll() is not None and proc.due is None:
                code, proc.popen = proc.popen.returncode, None
                proc.exits += 1
                kw = proc.action.kwargs
                limit = kw.get("respawn_max_retries", -1)
                if kw.get("respawn") and not self.is_shutdown and (limit < 0 or proc.exits <= limit):
                    proc.due = now + kw.get("respawn_delay", 0.0)
                self._dispatch("ProcessExited", proc.action, types.SimpleNamespace(returncode=code))
            if proc.due is not None and now >= proc.due and not self.is_shutdown:
                proc.due = None
                self._start(proc)

    def run(self, description, launch_arguments: dict[str, str], until, timeout_s: float) -> None:
        """Visit ``description``; handle events until ``until(self)`` or a Shutdown; then stop."""
        self.launch_configurations.update(launch_arguments)
        deadline = time.monotonic() + timeout_s
        try:
            for action in description:
                self.visit(action)
            while not self.is_shutdown and not until(self):
                assert time.monotonic() < deadline, "launch double: timed out\n" + "\n".join(self.lines[-40:])
                self._executor.spin_once(timeout_sec=0.02)
                while not self.events.empty():
                    self._handle(*self.events.get())
                self._poll_processes()
                due = [t for t in self._timers if t[0] <= time.monotonic()]
                for t in due:
                    self._timers.remove(t)
                    for a in t[1]:
                        self.visit(a)
        finally:
            self.stop()

    def stop(self) -> None:
        self.is_shutdown = True
        running = [p.popen for p in self._procs if p.popen is not None and p.popen.poll() is None]
        for popen in running:
            os.killpg(popen.pid, signal.SIGINT)
        for popen in running:
            try:
                popen.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(popen.pid, signal.SIGKILL)
                popen.wait()
        self._executor.shutdown()
        self._ros.destroy_node()

    def pids(self) -> dict[str, int]:
        return {p.name: p.popen.pid for p in self._procs if p.popen is not None}
