"""bag_recorder node: records topics into a rosbag2 MCAP bag (core: thermal_comp_common.bags.writer).

Subscribes at start-up to every topic it is given, with the type known up front (no
discovery wait, nothing early is lost), as raw (serialized) subscriptions, and writes the
bytes untouched. A steady-clock timer closes the open chunk every ``flush_period_s`` so a
crash loses at most that chunk.

Bag log time is the receive time on the node's clock (simulated time with use_sim_time), as
``ros2 bag record`` writes it; the header stamp stays in the message, and readers key instants
by it (``BagMessage.stamp_ns``). ``timestamps:=header`` logs the header stamp instead.

A re-send is written once: a stamped message byte-identical to the last one written on its
topic (machine_sim re-sends an instant whose acknowledgements are late, and the sensors, the
model and the bridge repeat theirs for it) is counted (``resends_skipped`` on ``/diagnostics``
and in the closing line), not written again; ``keep_resends:=true`` writes every copy. So each
topic holds each instant once (before, a cell under load held 160 copies of 59 instants on
every topic but the ground truth, which machine_sim did not re-send).

As an observer (machine_sim's ``wait_for_subscribers``) with ``expect_from_start``, it subscribes
to errors/ground_truth, the topic machine_sim checks, only once each expected topic has a matched
publisher: DDS matches each pair of processes on its own, so a participant's writer (the
sensors') may not know a remote recorder yet when machine_sim, which does, starts.

As a lock-step participant (``lockstep_participant``) the recorder loses nothing across a crash
and restart: it acknowledges instant t_k on ``sim_sync`` only once it has written a message
stamped t_k on every one of ``ack_topics`` and handed the file to the OS (fsynced with
``ack_fsync``), so machine_sim cannot run
ahead of a dead recorder; the restarted recorder gets the unacknowledged instant when
machine_sim re-sends it. The other participants' stamped outputs (``follow_topics``:
temperatures, predictions, offsets, ground truth) are covered too, so the last instant's are
written before machine_sim can finish and the graph be stopped (an acknowledgement of theirs
says they published, not that the recorder has it): a follow topic is expected at t_k when it
was written at the instant acknowledged before, so a bridge that is off or a topic nobody
publishes never holds the graph; one that stops (a bridge switched off) holds t_k at most
``follow_timeout_s`` wall seconds, then it is named (topic and publishing node) on the log and
on ``/diagnostics`` and not expected until it is written again. (Buffering in the publishers and replaying was the alternative; it
needs a second copy of every stream and a replay protocol, where lock-step reuses the
handshake every other node already speaks.) A write error (a full disk) stops the recorder with
exit code 1 and one error line: the bag is closed at what was on disk, marked incomplete
(:mod:`thermal_comp_common.bags.writer`), and nothing more is acknowledged. Its health (messages written, last instant
acknowledged) is on ``/diagnostics``. A message stamped more than ``max_stamp_ahead_s`` ahead of the
node's clock (a forged or broken publisher) is neither recorded nor acknowledged: counted on
``/diagnostics`` (status ``stamps``) and logged once per burst. Run: ``python -m thermal_comp.bags.recorder_node --ros-args
-p output:=BAG`` or ``thermal-comp record BAG``.
"""
from __future__ import annotations

import importlib
import pathlib
import time

from builtin_interfaces.msg import Time
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from thermal_comp_common.runtime import node_runtime as rt
from thermal_comp_common.bags.writer import BagIOError, BagWriter, TopicInfo, qos_dict, stamp_from_cdr
from thermal_comp_common.runtime.diagnostics import DIAGNOSTICS_QOS, TOPIC_DIAGNOSTICS, DiagnosticsPublisher
from thermal_comp_common.bags.msg_definitions import first_field_type, normalize_type
from thermal_comp_common.stamp_guard import StampGuard, admit, default_max_ahead_s, graph_clock_s, stamp_status
from thermal_comp_msgs.msg import SimSync

#: The topics recorded when none are given: relative name -> (type, QoS the publisher offers).
DEFAULT_TOPICS: dict[str, tuple[str, QoSProfile]] = {
    rt.TOPIC_MACHINE_STATE: ("thermal_comp_msgs/msg/MachineState", rt.SENSOR_QOS),
    rt.TOPIC_TWIN_SENSORS: ("thermal_comp_msgs/msg/TemperatureArray", rt.SENSOR_QOS),
    rt.TOPIC_TEMPERATURES: ("thermal_comp_msgs/msg/TemperatureArray", rt.SENSOR_QOS),
    rt.TOPIC_ERRORS_TRUE: ("thermal_comp_msgs/msg/ThermalErrors", rt.EVENT_QOS),
    rt.TOPIC_ERRORS_PREDICTED: ("thermal_comp_msgs/msg/ThermalErrors", rt.EVENT_QOS),
    rt.TOPIC_ERRORS_MEASURED: ("thermal_comp_msgs/msg/ThermalErrors", rt.EVENT_QOS),
    rt.TOPIC_OFFSETS: ("thermal_comp_msgs/msg/AxisOffsets", rt.EVENT_QOS),
    rt.TOPIC_MODEL_STATUS: ("thermal_comp_msgs/msg/ModelStatus", rt.LATCHED_QOS),
}
#: The graph's health, absolute topics every node publishes on (recorded with ``health``, shown
#: by the rerun view): name -> (type, QoS to subscribe with).
HEALTH_TOPICS: dict[str, tuple[str, QoSProfile]] = {
    TOPIC_DIAGNOSTICS: ("diagnostic_msgs/msg/DiagnosticArray", DIAGNOSTICS_QOS),
    "/rosout": ("rcl_interfaces/msg/Log", QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)),
}
#: Known topics that are not recorded by default but may be named on the command line.
OPTIONAL_TOPICS: dict[str, tuple[str, QoSProfile]] = {
    rt.TOPIC_SIM_SYNC: ("thermal_comp_msgs/msg/SimSync", rt.EVENT_QOS),
    "/clock": ("rosgraph_msgs/msg/Clock", rt.MONITOR_QOS),
    **HEALTH_TOPICS,
}
#: Receive-side queue depth for reliable topics (absorbs bursts of an as-fast-as-possible replay).
RECEIVE_DEPTH = 1000
# Bag log time, one default for the node and ``thermal-comp record``: the receive time, as rosbag2.
DEFAULT_TIMESTAMPS = "receive"


def parse_topic_arg(arg: str) -> tuple[str, str, QoSProfile]:
    """'name' (a known topic) or 'name:pkg/msg/Type' -> (name, type, QoS)."""
    name, sep, type_name = arg.partition(":")
    name = name.strip()
    if not name:
        raise ValueError(f"topics: {arg!r} has no topic name")
    known = {**DEFAULT_TOPICS, **OPTIONAL_TOPICS}
    if name.startswith("/") and name not in known:   # '/cell1/temperatures': a known topic in a namespace
        for rel in sorted(known, key=len, reverse=True):
            if not rel.startswith("/") and name.endswith("/" + rel):
                known = {**known, name: known[rel]}
                break
    if sep:
        qos = known.get(name, (None, rt.EVENT_QOS))[1]
        return name, normalize_type(type_name), qos
    if name not in known:
        raise ValueError(f"topics: {name!r} is not a known topic; give its type as "
                         f"'{name}:pkg/msg/Type' (known: {', '.join(sorted(known))})")
    return name, known[name][0], known[name][1]


def message_class(type_name: str):
    """The rclpy message class of 'pkg/msg/Type' (ValueError naming it if not installed)."""
    pkg, sub, name = normalize_type(type_name).split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{sub}"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {type_name!r} has no installed Python typesupport") from None


def starts_with_stamp(type_name: str) -> bool:
    """True if the type's first field is a std_msgs/Header or builtin_interfaces/Time."""
    return first_field_type(type_name) in ("std_msgs/msg/Header", "builtin_interfaces/msg/Time")


def _qos_to_dict(q: QoSProfile) -> dict:
    return qos_dict(reliability=q.reliability.name.lower(), durability=q.durability.name.lower(),
                    history=q.history.name.lower(), depth=q.depth)


def _receive_qos(q: QoSProfile) -> QoSProfile:
    """The publisher's QoS with a deep receive queue, latched (depth 1) topics too: a burst of
    model_status faster than this node takes them must queue, not overwrite (a latched
    writer still hands a late joiner only its own depth)."""
    return QoSProfile(history=q.history, depth=max(q.depth, RECEIVE_DEPTH),
                      reliability=q.reliability, durability=q.durability)


def topic_specs(topics, health: bool) -> list[tuple[str, str, QoSProfile]]:
    """(name, type, QoS) of every topic to record: ``topics`` (empty: the defaults), and with
    ``health`` the health topics not named already."""
    args = [t for t in topics if t.strip()]
    specs = [parse_topic_arg(a) for a in args] if args else [(n, t, q) for n, (t, q) in DEFAULT_TOPICS.items()]
    if health:
        specs += [(n, t, q) for n, (t, q) in HEALTH_TOPICS.items() if n not in {s[0] for s in specs}]
    return specs


#: The node's parameters.
PARAMS = [
    rt.Param("output", "", "bag folder to create (must not exist)"),
    rt.Param("topics", [""], "topics to record, 'name' or 'name:pkg/msg/Type'; "
             "empty: every default topic"),
    rt.Param("flush_period_s", 1.0, "close the open chunk this often (wall clock, s): "
             "a crash loses at most this much", lo=0.05, hi=3600.0),
    rt.Param("chunk_bytes", 262144, "close a chunk when it holds this many bytes",
             lo=1024, hi=64 * 2**20),
    rt.Param("timestamps", DEFAULT_TIMESTAMPS, "log time in the bag: the receive time on the "
             "node's clock (as rosbag2 writes it), or the message's own header stamp",
             choices=("header", "receive")),
    rt.Param("compression", "zstd", "chunk compression", choices=("zstd", "lz4", "none")),
    rt.Param("on_existing", "continue", "when 'output' exists (a restart after a crash): "
             "continue in a new bag 'output.2', 'output.3', ... and leave the old one as it "
             "is, or fail", choices=("continue", "fail")),
    rt.Param("lockstep_participant", False, "acknowledge instant t_k on sim_sync once a message "
             "stamped t_k of every ack_topics topic is written (and fsynced with ack_fsync)"),
    rt.Param("ack_topics", ["machine_state", "twin/sensor_readings"], "lock-step: topics "
             "whose message for t_k must be written before t_k is acknowledged (topics "
             "machine_sim re-sends; ones not recorded are ignored)"),
    rt.Param("follow_topics", [rt.TOPIC_TEMPERATURES, rt.TOPIC_ERRORS_PREDICTED, rt.TOPIC_OFFSETS,
                               rt.TOPIC_ERRORS_TRUE], "lock-step: topics the other participants "
             "publish for t_k; one written at the instant acknowledged before must be written "
             "at t_k too before t_k is acknowledged (ones not recorded are ignored)"),
    rt.Param("expect_from_start", [""], "lock-step: follow topics expected at the first instant "
             "this recorder acknowledges too (the cell's participants publish them from its first "
             "instant: a message lost before the recorder matched its publisher is re-sent); as an "
             "observer: errors/ground_truth, the topic machine_sim's wait_for_subscribers checks, is "
             "subscribed only once each of these topics has a matched publisher (observer_wait_s)"),
    rt.Param("observer_wait_s", 60.0, "observer with expect_from_start: wall s to wait for their "
             "publishers before subscribing to errors/ground_truth anyway (the topics still unheard "
             "are named)", lo=0.1, hi=3600.0),
    rt.Param("follow_timeout_s", 10.0, "lock-step: wall s to wait for an expected follow topic "
             "once every ack_topics topic of t_k is written; then it is named and no longer "
             "expected until written again", lo=0.1, hi=3600.0),
    rt.Param("health", False, "also record the graph's health: /diagnostics and /rosout "
             "(with the default topics; the demo's recorder does)"),
    rt.Param("keep_resends", False, "write every copy of a re-sent message (same topic, same "
             "stamp, same bytes as the last one written on the topic); default: write it once"),
    rt.Param("max_stamp_ahead_s", 0.0, "a message stamped more than this ahead of the node's clock, s, is "
             "neither recorded nor acknowledged (counted, logged once per burst); 0 = 60 s on wall "
             "time, 3600 s with use_sim_time", lo=0.0, hi=86400.0),
    rt.Param("ack_fsync", False, "lock-step: fsync the bag before each acknowledgement (survives a "
             "power loss, a few ms per instant); without, the written chunk is handed to the OS "
             "first, which survives a crash or kill of this process"),
]


class BagRecorderNode(Node):
    """Records the configured topics into ``output`` until shut down."""

    def __init__(self, context=None, **kwargs):
        super().__init__("bag_recorder", context=context, **kwargs)
        p = rt.declare_parameters(self, PARAMS)
        if not p["output"]:
            raise ValueError("parameter 'output': a bag folder path is required")
        self._use_header = p["timestamps"] == "header"
        self._keep_resends = bool(p["keep_resends"])
        self._ack_fsync = bool(p["ack_fsync"])
        self._last_written: dict[str, bytes] = {}     # topic -> the last stamped message written
        self.resends_skipped = 0
        self._stamp_bound = default_max_ahead_s(p["max_stamp_ahead_s"],
                                                bool(self.get_parameter("use_sim_time").value))
        self.stamps: dict[str, StampGuard] = {}       # topic -> its guard (stamped topics, made on first use)
        specs = topic_specs(p["topics"], p["health"])
        gated = self._gate_topic(specs, p)
        infos = self._subscribe(specs, deferred=gated)
        self._ack_topics: set[str] = set()
        self._follow_topics: set[str] = set()
        self._pending: dict[int, set[str]] = {}       # stamp -> ack topics written at it (until acknowledged)
        self._follow_seen: dict[int, set[str]] = {}   # stamp -> follow topics written at it (from the last ack on)
        self._complete_since: dict[int, float] = {}  # instant -> steady time its ack_topics were complete
        self.acked_ns: int | None = None
        self.follow_dropped: list[tuple[str, int]] = []   # (topic, instant) acknowledged without it
        self._sync_pub = None
        if p["lockstep_participant"]:
            self._setup_lockstep(p)
        elif gated is not None:
            self._setup_observer_gate(p, gated)
        # The bag last: a start refused for a parameter leaves no empty, unclosed bag behind (which a
        # restart would then step over into OUTPUT.2).
        output = self._output_path(p["output"], p["on_existing"])
        self.writer = BagWriter(output, infos, chunk_bytes=p["chunk_bytes"], compression=p["compression"],
                                custom_data={"recorded_by": "thermal_comp.bags.recorder_node"})
        try:
            self._flush_timer = self.create_timer(p["flush_period_s"], self._periodic,
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))
            self.diag = DiagnosticsPublisher(self, hardware_id=output)
        except BaseException:
            self.writer.close()      # run_node closes only a node it got: the bag is closed here
            raise
        self.diag.set("recorder", "OK", f"recording into {output}", messages=0)
        self.get_logger().info(f"recording {len(infos)} topics into {output}: "
                               + ", ".join(i.name for i in infos))

    def _subscribe(self, specs, deferred: str | None = None) -> list[TopicInfo]:
        """A raw subscription per (name, type, QoS); the bag's topic list, names resolved. The
        ``deferred`` topic is in the list but subscribed later (:meth:`_open_gate`)."""
        self._subs = []
        self._deferred = None
        self._gate_wait: set[str] = set()
        infos = []
        for name, type_name, qos in specs:
            cls = message_class(type_name)
            topic = self.resolve_topic_name(name)
            if topic == deferred:
                self._deferred = (len(self._subs), cls, name, _receive_qos(qos))
                self._subs.append((None, topic, starts_with_stamp(type_name)))
            else:
                sub = self.create_subscription(cls, name, self._callback_for(len(self._subs)),
                                               _receive_qos(qos), raw=True)
                self._subs.append((sub, topic, starts_with_stamp(type_name)))
            infos.append(TopicInfo(topic, type_name, [_qos_to_dict(qos)]))
        return infos

    def _gate_topic(self, specs, p: dict) -> str | None:
        """The ground-truth topic when this recorder is an observer told what to expect from the
        start: machine_sim publishes its first instant once an observer subscribes to it, and DDS
        matches each pair of processes on its own, so a participant's writer (the sensors') may
        not know this recorder yet; holding that subscription back until every expected topic has
        a matched publisher keeps their first instants. None: nothing is held back."""
        expected = [t for t in p["expect_from_start"] if t.strip()]
        truth = self.resolve_topic_name(rt.TOPIC_ERRORS_TRUE)
        if p["lockstep_participant"] or not expected:
            return None
        recorded = {self.resolve_topic_name(n) for n, _, _ in specs}
        unknown = sorted({self.resolve_topic_name(t) for t in expected} - recorded)
        if unknown:
            raise ValueError(f"parameter 'expect_from_start': {unknown} is not a recorded topic "
                             "(a topic expected from the first instant must be recorded)")
        return truth if truth in recorded else None

    def _setup_observer_gate(self, p: dict, gated: str) -> None:
        self._gate_wait = {self.resolve_topic_name(t) for t in p["expect_from_start"] if t.strip()} - {gated}
        self._gate_deadline = time.monotonic() + float(p["observer_wait_s"])
        self._gate_timer = self.create_timer(0.1, self._open_gate, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def unheard_topics(self) -> list[str]:
        """Observer gate: the expected topics no publisher of which has matched this recorder yet."""
        subs = {topic: sub for sub, topic, _ in self._subs if sub is not None}
        return sorted(t for t in self._gate_wait if subs[t].get_publisher_count() == 0)

    def _open_gate(self) -> None:
        """Subscribe to the held-back topic once every expected topic is heard, or at the deadline
        (the topics still unheard named on the log: their first instants may be missing)."""
        if self._deferred is None:
            return
        unheard = self.unheard_topics()
        if unheard and time.monotonic() < self._gate_deadline:
            return
        index, cls, name, qos = self._deferred
        sub = self.create_subscription(cls, name, self._callback_for(index), qos, raw=True)
        self._subs[index] = (sub, sub.topic_name, self._subs[index][2])
        self._deferred = None
        self._gate_timer.cancel()
        if unheard:
            self.get_logger().warning(f"no publisher of {', '.join(unheard)} matched within observer_wait_s; "
                                      f"subscribing to {sub.topic_name} anyway: their first instants may be missing")
        else:
            self.get_logger().info(f"every expected topic has a publisher: subscribed to {sub.topic_name}")

    def _setup_lockstep(self, p: dict) -> None:
        """Lock-step participant: the ack, follow and start topics checked, sim_sync publisher,
        the follow timeout's timer."""
        self._ack_topics = self._stamped_topics(p["ack_topics"])
        if not self._ack_topics:
            raise ValueError(f"parameter 'ack_topics': none of {list(p['ack_topics'])} is a "
                             "recorded topic with a stamp")
        self._start_topics = self._stamped_topics(p["expect_from_start"]) - self._ack_topics
        unknown = sorted({self.resolve_topic_name(t) for t in p["expect_from_start"] if t.strip()}
                         - self._start_topics - self._ack_topics)
        if unknown:
            raise ValueError(f"parameter 'expect_from_start': {unknown} is not a recorded topic with "
                             "a stamp (a topic expected from the first instant must be recorded)")
        self._follow_topics = (self._stamped_topics(p["follow_topics"]) | self._start_topics) - self._ack_topics
        self._follow_timeout_s = float(p["follow_timeout_s"])
        self._sync_pub = self.create_publisher(SimSync, rt.TOPIC_SIM_SYNC, rt.EVENT_QOS)
        if self._follow_topics:
            self.create_timer(min(0.25, self._follow_timeout_s / 4), self._check_follow,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _output_path(self, output: str, on_existing: str) -> str:
        """``output``, or after a crash (it exists, ``on_existing`` continue) the next free ``output.k``."""
        if on_existing != "continue" or not pathlib.Path(output).exists():
            return output
        k = 2
        while pathlib.Path(f"{output}.{k}").exists():
            k += 1
        self.get_logger().warning(f"{output} exists (an earlier run, or this recorder was restarted "
                                  f"after a crash): it is kept as it is; recording continues in {output}.{k}")
        return f"{output}.{k}"

    def _callback_for(self, index: int):
        def on_message(data: bytes) -> None:
            if self.writer.closed:
                return                 # stopped on a write error: the bag holds what was on disk
            try:
                self._record(index, data)
            except BagIOError as exc:
                self._stop_on_write_error(exc)
        return on_message

    def _record(self, index: int, data: bytes) -> None:
        """Write one message (a re-send once) and acknowledge what it completes."""
        _, topic, stamped = self._subs[index]
        now = self.get_clock().now().nanoseconds
        stamp = stamp_from_cdr(data) if stamped else None
        if stamp is not None and not self._stamp_ok(topic, stamp, now):
            return                         # a stamp off the graph's clock: not recorded, never acknowledged
        if stamp is not None and not self._keep_resends and self._last_written.get(topic) == data:
            self.resends_skipped += 1      # a re-sent instant: written once, acknowledged again
        else:
            t = stamp if self._use_header else None
            self.writer.write(topic, now if t is None else t, data, publish_time_ns=now)
            if stamp is not None:
                self._last_written[topic] = bytes(data)
        if stamp is not None and (topic in self._ack_topics or topic in self._follow_topics):
            self._written(topic, stamp)

    def _stamp_ok(self, topic: str, stamp_ns: int, now_ns: int) -> bool:
        """The stamp is not ahead of this node's clock by more than the bound (behind is fine: a
        recorder records what was late); else refused, counted, logged once per burst."""
        guard = self.stamps.setdefault(topic, StampGuard(topic, self._stamp_bound, forward_only=False))
        check, refresh = admit(guard, stamp_ns / 1e9, graph_clock_s(now_ns), self.get_logger().warning,
                               "; not recorded, not acknowledged")
        if refresh:
            level, text, values = stamp_status(self.stamps.values(), max_ahead_s=self._stamp_bound)
            self.diag.set("stamps", level, text, **values)
        return check.accepted

    def _stop_on_write_error(self, exc: BagIOError) -> None:
        """A write failed (disk full...): the writer closed the bag at what was on disk, marked
        incomplete; say so in one line and stop the node with exit code 1 (nothing is
        acknowledged any more, so machine_sim does not run ahead of a recorder that lost data)."""
        self.exit_code = 1
        self.get_logger().error(f"recording stopped: {exc}")
        self.diag.set("recorder", "ERROR", f"recording stopped: {exc}", messages=self.writer.message_count)
        self.context.try_shutdown()

    def _stamped_topics(self, names) -> set[str]:
        wanted = {self.resolve_topic_name(t) for t in names if t.strip()}
        return {topic for _, topic, stamped in self._subs if topic in wanted and stamped}

    def _expected_follow(self, stamp_ns: int) -> set[str]:
        """The follow topics t_k waits for: those written at the instant acknowledged before it,
        ``expect_from_start`` at the first (none for an instant acknowledged already, a re-send)."""
        if self.acked_ns is None:
            return self._start_topics
        if stamp_ns <= self.acked_ns:
            return set()
        return self._follow_seen.get(self.acked_ns, set())

    def _written(self, topic: str, stamp_ns: int) -> None:
        """Acknowledge t_k once every ack topic and every expected follow topic has a written
        message stamped t_k (handed to the OS first)."""
        if topic in self._follow_topics:
            self._follow_seen.setdefault(stamp_ns, set()).add(topic)
            if stamp_ns in self._complete_since and not self._expected_follow(stamp_ns) - self._follow_seen[stamp_ns]:
                self._acknowledge(stamp_ns)
            return
        seen = self._pending.setdefault(stamp_ns, set())
        seen.add(topic)
        if seen != self._ack_topics:
            return
        if self._expected_follow(stamp_ns) - self._follow_seen.get(stamp_ns, set()):
            self._complete_since.setdefault(stamp_ns, time.monotonic())
            return
        self._acknowledge(stamp_ns)

    def _check_follow(self) -> None:
        """An expected follow topic not written within ``follow_timeout_s`` of its instant's
        ack_topics: named, and the instant acknowledged without it (nothing waits forever)."""
        now = time.monotonic()
        for stamp_ns, since in sorted(self._complete_since.items()):
            if stamp_ns not in self._complete_since or now - since < self._follow_timeout_s:
                continue     # acknowledged meanwhile (with an earlier instant of this loop), or not yet due
            missing = self._expected_follow(stamp_ns) - self._follow_seen.get(stamp_ns, set())
            for topic in sorted(missing):
                nodes = sorted({i.node_name for i in self.get_publishers_info_by_topic(topic)}) or ["none"]
                text = (f"{topic} (publisher: {', '.join(nodes)}): no message stamped t = {stamp_ns / 1e9:.0f} s "
                        f"within follow_timeout_s = {self._follow_timeout_s:g} s of the instant; acknowledged "
                        "without it, not expected until it is written again")
                self.get_logger().warning(text)
                self.diag.set("recorder", "WARN", text, messages=self.writer.message_count)
                self.follow_dropped.append((topic, stamp_ns))
            self._acknowledge(stamp_ns)

    def _acknowledge(self, stamp_ns: int) -> None:
        if self.writer.closed:
            return                     # stopped on a write error: nothing more is acknowledged
        try:
            self.writer.sync(fsync=self._ack_fsync)
        except BagIOError as exc:
            self._stop_on_write_error(exc)
            return
        for k in [k for k in self._pending if k <= stamp_ns]:
            del self._pending[k]
        if self.acked_ns is None or stamp_ns > self.acked_ns:
            self.acked_ns = stamp_ns
            # the follow topics written at the acknowledged instant stay: they say what t_{k+1} expects
            for k in [k for k in self._follow_seen if k < stamp_ns]:
                del self._follow_seen[k]
        for k in [k for k in self._complete_since if k <= self.acked_ns]:
            del self._complete_since[k]
        self._sync_pub.publish(SimSync(node_name=self.get_name(), processed_until=Time(
            sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)))

    def _periodic(self) -> None:
        if self.writer.closed:
            return
        try:
            self.writer.flush()
        except BagIOError as exc:
            self._stop_on_write_error(exc)
            return
        values = {"messages": self.writer.message_count, "resends_skipped": self.resends_skipped,
                  "follow_dropped": len(self.follow_dropped)}
        if self.acked_ns is not None:
            values["acknowledged_until_s"] = self.acked_ns / 1e9
        self.diag.update_values("recorder", **values)

    def drain_activity(self) -> int:
        """Messages written so far: after a stop signal the node runtime spins on while this
        still moves, so what already arrived is written before the bag is closed."""
        return self.writer.message_count

    def close(self) -> None:
        try:
            self.writer.close()
        except BagIOError as exc:
            self.exit_code = 1
            self.get_logger().error(f"recording stopped: {exc}")
            return
        if self.writer.incomplete:
            return     # said when it stopped
        self.get_logger().info(f"bag {self.writer.path} closed: {self.writer.message_count} messages"
                               f" ({self.resends_skipped} re-sent copies not written again"
                               + (f"; {len(self.follow_dropped)} instants acknowledged without an expected message: "
                                  + ", ".join(f"{t} at {k / 1e9:.0f} s" for t, k in self.follow_dropped[:5])
                                  if self.follow_dropped else "") + ")")


def main(args=None) -> int:
    return rt.run_node(BagRecorderNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
