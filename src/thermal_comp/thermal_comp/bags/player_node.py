"""bag_player node: re-publishes a bag's serialized messages and drives /clock (core: bag_player).

Instant by instant (messages with the same bag time): publish ``/clock`` = that time, then
the messages in recorded order. Pacing:

- ``rate`` R: bag time runs R times faster than wall time; between instants ``/clock`` is
  also published at ``clock_hz`` (wall) so sim-time timers advance smoothly.
- ``as_fast_as_possible``: no waiting on the wall clock; after each instant the player
  waits until every subscriber acknowledged every message (reliable QoS) and, with
  ``lockstep_participants``, until each of them reported ``SimSync.processed_until`` >= the
  instant - the lock-step handshake of machine_sim - so nothing is dropped.
  Acknowledgement is DDS delivery into the subscriber's queue, not processing: a keep-last
  subscriber slower than the player can still lose what overflows its queue depth; name
  such nodes in ``lockstep_participants`` (application-level flow control).

Before the first message it waits (up to ``match_timeout_s``) until every publisher has
``wait_for_subscribers`` matched subscriptions. A damaged bag is replayed up to the damage,
which is logged; ``result`` holds the outcome. Run: ``thermal-comp play BAG`` or
``python -m thermal_comp.bags.player_node --ros-args -p bag:=BAG``.
"""
from __future__ import annotations

import os
import pathlib
import tempfile
import threading
import time

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from thermal_comp_common.plain_output import progress
from thermal_comp_common.runtime import node_runtime as rt
from thermal_comp_common.bags.reader import BagContents, instants, read_bag, wall_delay_s
from thermal_comp_msgs.msg import SimSync
from thermal_comp.bags.recorder_node import message_class

CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                       reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: Publisher depth for replayed reliable volatile topics (never below the recorded depth).
PUBLISH_DEPTH = 1000


def qos_from_dict(d: dict | None) -> QoSProfile:
    """rclpy QoS from a rosbag2 offered-QoS dict (reliable/volatile defaults)."""
    d = d or {}
    durable = d.get("durability") == "transient_local"
    depth = int(d.get("depth") or 1)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth if durable else max(depth, PUBLISH_DEPTH),
        reliability=(ReliabilityPolicy.BEST_EFFORT if d.get("reliability") == "best_effort"
                     else ReliabilityPolicy.RELIABLE),
        durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE)


class PlaybackResult:
    def __init__(self) -> None:
        self.done = threading.Event()
        self.published = 0
        self.instants = 0
        self.skipped_topics: list[str] = []
        self.damage: str | None = None
        self.error: str | None = None
        self.last_time_ns: int | None = None


class BagPlayerNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("bag_player", context=context, **kwargs)
        p = rt.declare_parameters(self, [
            rt.Param("bag", "", "bag folder (metadata.yaml + .mcap) or .mcap file to replay"),
            rt.Param("rate", 1.0, "bag seconds per wall second", lo=1e-3, hi=1e6),
            rt.Param("as_fast_as_possible", False, "no wall-clock pacing (acknowledged delivery)"),
            rt.Param("clock_hz", 10.0, "/clock updates per wall second between instants (rate mode)",
                     lo=0.1, hi=1000.0),
            rt.Param("topics", [""], "replay only these topics (resolved names); empty: all"),
            rt.Param("wait_for_subscribers", 0, "before starting, wait until each publisher has "
                     "this many matched subscriptions", lo=0, hi=1000),
            rt.Param("match_timeout_s", 10.0, "give up waiting for subscribers after this (wall s)",
                     lo=0.0, hi=3600.0),
            rt.Param("lockstep_participants", [""], "node names whose SimSync acks each instant "
                     "(as_fast_as_possible); empty: none"),
            rt.Param("ack_timeout_s", 30.0, "wall seconds to wait for acknowledgements of one instant",
                     lo=0.01, hi=3600.0),
            rt.Param("shutdown_when_done", True, "stop the node after the last message"),
            rt.Param("progress", False, "show a progress bar in bag time on stderr"),
        ])
        if not p["bag"]:
            raise ValueError("parameter 'bag': a bag path is required")
        self.p = p
        self.result = PlaybackResult()
        self.contents: BagContents = read_bag(p["bag"])
        for w in self.contents.warnings:
            self.get_logger().warning(w)
        only = {t for t in p["topics"] if t}
        self._pubs = {}
        for name, spec in self.contents.topics.items():
            if only and name not in only:
                continue
            if name == "/clock":   # the player drives /clock itself from the bag's times
                self.result.skipped_topics.append(name)
                continue
            try:
                cls = message_class(spec.type)
            except ValueError as exc:
                self.result.skipped_topics.append(name)
                self.get_logger().warning(f"topic {name!r} not replayed: {exc}")
                continue
            self._pubs[name] = self.create_publisher(cls, name, qos_from_dict((spec.qos or [None])[0]))
        self._clock_pub = self.create_publisher(Clock, "/clock", CLOCK_QOS)
        self._participants = [n for n in p["lockstep_participants"] if n]
        self._acked: dict[str, int] = {}
        self._ack_cv = threading.Condition()
        if self._participants:
            self.create_subscription(SimSync, rt.TOPIC_SIM_SYNC, self._on_sync, rt.EVENT_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bag_player", daemon=True)
        self._thread.start()

    # ----------------------------------------------------------------------------------
    def _on_sync(self, msg) -> None:
        t = msg.processed_until.sec * 1_000_000_000 + msg.processed_until.nanosec
        with self._ack_cv:
            self._acked[msg.node_name] = max(t, self._acked.get(msg.node_name, -1))
            self._ack_cv.notify_all()

    def _publish_clock(self, t_ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self._clock_pub.publish(msg)

    def _wait_for_subscribers(self) -> None:
        need = self.p["wait_for_subscribers"]
        if need <= 0:
            return
        deadline = time.monotonic() + self.p["match_timeout_s"]
        pubs = list(self._pubs.items())
        while not self._stop.is_set():
            missing = [n for n, pub in pubs if pub.get_subscription_count() < need]
            if not missing:
                return
            if time.monotonic() > deadline:
                self.get_logger().warning(f"starting without {need} subscriber(s) on: {', '.join(missing)}")
                return
            self._stop.wait(0.01)

    def _wait_acked(self, t_ns: int, pubs) -> None:
        timeout = self.p["ack_timeout_s"]
        for pub in pubs:
            if pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE:
                if not pub.wait_for_all_acked(Duration(seconds=timeout)):
                    self.get_logger().warning(f"{pub.topic_name}: not acknowledged within {timeout} s")
        if self._participants:
            deadline = time.monotonic() + timeout
            with self._ack_cv:
                while not self._stop.is_set():
                    lagging = [n for n in self._participants if self._acked.get(n, -1) < t_ns]
                    if not lagging:
                        return
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise TimeoutError(f"lock-step participants {lagging} did not acknowledge "
                                           f"t={t_ns * 1e-9:.3f} s within {timeout} s")
                    self._ack_cv.wait(min(left, 0.1))

    def _make_room(self, pub, unacked: dict) -> None:
        """Before a reliable writer's history (keep-last ``depth``) would drop a sample no
        subscriber has acknowledged, wait for the acknowledgements: nothing is overwritten at
        any rate (the replay falls behind the asked rate instead, see the summary line)."""
        if pub.qos_profile.reliability != ReliabilityPolicy.RELIABLE or unacked.get(pub, 0) < pub.qos_profile.depth:
            return
        timeout = self.p["ack_timeout_s"]
        if not pub.wait_for_all_acked(Duration(seconds=timeout)):
            self.get_logger().warning(f"{pub.topic_name}: not acknowledged within {timeout} s")
        unacked[pub] = 0

    def _run(self) -> None:
        r = self.result
        try:
            r.damage = self.contents.damage
            self._wait_for_subscribers()
            msgs = [m for m in self.contents.messages if m.topic in self._pubs]
            start = msgs[0].stamp_ns if msgs else 0
            wall0 = time.monotonic()
            fast = self.p["as_fast_as_possible"]
            rate = self.p["rate"]
            bar = None
            unacked: dict = {}     # publisher -> messages published since its last acknowledgement
            if self.p["progress"] and msgs:
                bar = progress(round((msgs[-1].stamp_ns - start) / 3.6e12, 3), "play", "sim h",
                               decimals=2)
            for t_ns, group in instants(msgs):
                if self._stop.is_set():
                    break
                if not fast:
                    due = wall0 + wall_delay_s(t_ns, start, rate)
                    period = 1.0 / self.p["clock_hz"]
                    while not self._stop.is_set():
                        now = time.monotonic()
                        if now >= due:
                            break
                        self._stop.wait(min(period, due - now))
                        now = min(time.monotonic(), due)
                        # float round-off may land 1 ns past the instant: /clock never goes back
                        self._publish_clock(min(t_ns, start + int((now - wall0) * rate * 1e9)))
                self._publish_clock(t_ns)
                used = []
                for m in group:
                    pub = self._pubs[m.topic]
                    self._make_room(pub, unacked)
                    pub.publish(m.data)
                    unacked[pub] = unacked.get(pub, 0) + 1
                    used.append(pub)
                    r.published += 1
                r.instants += 1
                r.last_time_ns = t_ns
                if bar is not None:
                    bar.to((t_ns - start) / 3.6e12)
                if fast:
                    self._wait_acked(t_ns, dict.fromkeys(used))
                    unacked.clear()
            if bar is not None:
                bar.close()
        except Exception as exc:  # report, never crash the process
            r.error = f"{exc.__class__.__name__}: {exc}"
            self.get_logger().error(f"playback stopped: {r.error}")
        finally:
            summary = f"replayed {r.published} messages in {r.instants} instants"
            if r.last_time_ns is not None:
                summary += f", up to t={r.last_time_ns * 1e-9:.3f} s"
                wall = time.monotonic() - wall0
                if not self.p["as_fast_as_possible"] and wall > 0 and r.instants > 1:
                    summary += (f"; {(r.last_time_ns - start) * 1e-9 / wall:.4g} bag s per wall s "
                                f"(asked {self.p['rate']:g})")
            self.get_logger().info(summary)
            if r.damage:
                self.get_logger().error(f"bag damaged, replay stopped there: {r.damage}")
            for pub in self._pubs.values():   # deliver the tail before a shutdown
                if pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE and self.context.ok():
                    pub.wait_for_all_acked(Duration(seconds=self.p["ack_timeout_s"]))
            r.done.set()
            if self.p["shutdown_when_done"] and self.context.ok():
                self.context.try_shutdown()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


#: Fast DDS (Jazzy: Fast DDS 2.x) writer profile of the player: a reliable writer learns that a
#: sample was received from the reader's ACKNACK, which Fast DDS sends in answer to a writer
#: heartbeat - every 3 s by default, so an acknowledged instant could take up to 3 s. 5 ms
#: makes ``wait_for_all_acked`` return within milliseconds. QoS still comes from the code.
PLAYER_DDS_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <data_writer profile_name="thermal_comp_bag_player" is_default_profile="true">
    <times><heartbeatPeriod><sec>0</sec><nanosec>5000000</nanosec></heartbeatPeriod></times>
  </data_writer>
</profiles>
"""
PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"


def use_fast_heartbeat() -> str | None:
    """Point Fast DDS at :data:`PLAYER_DDS_PROFILE` unless the user set a profile file.

    Must run before the ROS context is created. Returns the profile path used (None if the
    user's own file is kept).
    """
    if os.environ.get(PROFILES_ENV):
        return None
    path = pathlib.Path(tempfile.gettempdir()) / f"thermal_comp_bag_player_{os.getuid()}.xml"
    if not path.is_file() or path.read_text() != PLAYER_DDS_PROFILE:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(PLAYER_DDS_PROFILE)
        tmp.replace(path)
    os.environ[PROFILES_ENV] = str(path)
    return str(path)


def main(args=None) -> int:
    use_fast_heartbeat()
    holder: dict = {}

    def factory(context):
        holder["node"] = BagPlayerNode(context=context)
        return holder["node"]

    factory.__name__ = "bag_player"
    code = rt.run_node(factory, args)
    node = holder.get("node")
    if code == 0 and node is not None:
        if node.result.error:
            return 1
        if node.result.damage:
            return 3
    return code


if __name__ == "__main__":
    raise SystemExit(main())
