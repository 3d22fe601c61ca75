"""`bag_player`: replays a ROS 1 bag, a ROS 2 bag (sqlite3 / mcap) or a bare mcap onto ROS 2 topics.

    bag_player BAG [--ros-args -p rate:=2.0 -p start_offset_s:=1.5 -p loop:=true
                                -p lossless:=true -r /camera/rgb/image_color:=/image ...]

Messages go out as recorded (raw CDR from `io.bag_messages`, no decoding) at the recorded log times x `rate`,
with `/clock` following the bag's time; looping, each pass later by the bag's duration (header stamps too). Lossless mode (`lossless:=true`) waits for subscribers, for DDS-level
acknowledgements and for the processing acks of the nodes on `ack_topic` (one frame in flight), and re-sends
`confirm_topics` until confirmed; the steps are in `play` and its helpers. The timing logic is ROS-free, in
`changing_slam_ros.io.playback`. Topics and parameters: docs/nodes.md#bag_player.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from rclpy.duration import Duration
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header

from changing_slam_ros.errors import BagError, ConfigError
from changing_slam_ros.io.bag_messages import BagMessages
from changing_slam_ros.io.playback import (
    NS_PER_S,
    PlaybackClock,
    PlaybackOptions,
    PlaybackProgress,
    first_bag_ns,
    parse_remaps,
    plan,
    resume_bag_ns,
)
from changing_slam_ros.nodes.node_help import NodeHelp, ParamSpec, first_line
from changing_slam_ros.nodes.node_runner import declare_parameters, message_class, run_node, undeclared_parameters
from changing_slam_ros.nodes.qos_events import QuietQosEvents

STRING_ARRAY = Parameter.Type.STRING_ARRAY

BAG_PLAYER_PARAMETERS: tuple[ParamSpec, ...] = (
    ("bag", "", "ROS 1 .bag, ROS 2 bag folder or .mcap file to play (or the first argument)"),
    ("rate", 1.0, "playback speed factor relative to the recorded timing"),
    ("start_offset_s", 0.0, "seconds of the bag skipped at the start"),
    ("loop", False, "play again from the offset after the end, until stopped; each pass's log times and header "
                    "stamps shifted by the bag's duration (plus one frame) more, so time keeps running forward"),
    ("loop_passes", 0, "loop: passes in all, then the player ends (0 = until stopped)"),
    ("first_pass", 0, "resume a stopped playback in this pass (0-based; loop only; `changing-slam graph` sets it)"),
    ("resume_at_s", 0.0, "resume the first pass this many seconds after start_offset_s (a restarted player)"),
    ("topics", STRING_ARRAY, "bag topics to play; empty = all"),
    ("remap", STRING_ARRAY, "topic renames 'from:=to' (as well as --ros-args -r)"),
    ("publish_clock", True, "publish rosgraph_msgs/Clock on /clock"),
    ("clock_hz", 100.0, "/clock publishing rate while waiting between messages"),
    ("qos_depth", 10, "publisher history depth (ignored in lossless mode: KEEP_ALL)"),
    ("progress_period_s", 2.0, "seconds between progress log lines"),
    ("lossless", False, "wait for subscribers and acknowledgements instead of dropping"),
    ("dds_ack_wait", True, "lossless: wait for every reliable subscription's DDS-level ack after each "
                           "message; across processes Fast DDS acks on its heartbeat (up to 3 s)"),
    ("wait_subscribers", False, "also without lossless: wait for subscribers (as lossless does) before playing"),
    ("wait_for_topics", STRING_ARRAY, "lossless: topics that must have subscribers; empty = ack_topics or all"),
    ("min_subscribers", 1, "lossless: subscriptions each waited-for ack topic (every topic without ack_topics) "
                           "needs before playing; other waited-for topics need one"),
    ("wait_subscribers_timeout_s", 60.0, "lossless: give up (error) after this long without subscribers"),
    ("ack_topics", STRING_ARRAY, "lossless: bag topics whose messages wait for a processing ack"),
    ("ack_topic", "/bag_player/ack", "lossless: std_msgs/Header acks (stamp = acknowledged stamp)"),
    ("ack_count", 1, "lossless: distinct acknowledging nodes awaited per message on ack_topics"),
    ("ack_timeout_s", 2.0, "lossless: longest wait per message for acks (DDS and processing)"),
    ("confirm_topics", STRING_ARRAY, "lossless: bag topics a subscriber must confirm (a Header on ack_topic "
                                     "with frame_id = the topic) before the next ack_topics message"),
    ("confirm_resend_s", 0.5, "lossless: re-send an unconfirmed confirm_topics message this often"),
    ("diagnostics_period_s", 5.0, "seconds between /diagnostics reports while playing (0 = off)"),
)


@dataclass
class PlaybackResult:
    """What a `play()` call did."""

    published: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    passes: int = 0
    ack_timeouts: int = 0
    dds_ack_timeouts: int = 0
    confirm_resends: int = 0  # lossless: messages of confirm_topics sent again until a subscriber confirmed one
    confirm_timeouts: int = 0
    wall_s: float = 0.0
    cpu_s: float = 0.0  # this process's CPU time during play() (all threads)
    completed: bool = False
    error: str = ""


class BagPlayerNode(QuietQosEvents, Node):
    """Publishes a bag's messages on schedule; call `play(executor)` (it returns at the end of the bag)."""

    def __init__(self, bag_path: str | None = None, **node_kwargs: Any) -> None:
        super().__init__("bag_player", **node_kwargs)
        p = self._declare_parameters(bag_path)
        self.options = PlaybackOptions(
            rate=p["rate"],
            start_offset_s=p["start_offset_s"],
            loop=p["loop"],
            topics=tuple(p["topics"]),
            remap=parse_remaps(p["remap"]),
            loop_passes=p["loop_passes"],
            first_pass=p["first_pass"],
            resume_at_s=p["resume_at_s"],
        )
        self.lossless: bool = p["lossless"]
        self._wait_subscribers: bool = p["lossless"] or p["wait_subscribers"]
        self._dds_ack_wait: bool = p["dds_ack_wait"]
        self._clock_period_ns = round(NS_PER_S / p["clock_hz"]) if p["publish_clock"] else None
        self._progress_period_ns = round(p["progress_period_s"] * NS_PER_S)
        self._wait_topics: list[str] = p["wait_for_topics"]
        self._min_subscribers: int = p["min_subscribers"]
        self._wait_subscribers_timeout_s: float = p["wait_subscribers_timeout_s"]
        self._ack_topics = set(p["ack_topics"])
        self._ack_count: int = p["ack_count"]
        self._ack_timeout_s: float = p["ack_timeout_s"]
        self._confirm_topics: list[str] = p["confirm_topics"]
        self._confirm_resend_s: float = p["confirm_resend_s"]
        if not p["bag"]:
            raise ConfigError("bag_player: no bag given (bag_player BAG, or -p bag:=PATH)")

        self.bag = BagMessages(p["bag"]).open()
        try:
            self.bag_publishers = self._make_publishers(p["qos_depth"])
        except BaseException:
            self.bag.close()
            raise
        self._clock_pub = self.create_publisher(Clock, "/clock", QoSProfile(depth=10))
        unknown = undeclared_parameters(self)
        if unknown:
            self.bag.close()
            known = sorted(n for n in self._parameters if not n.startswith("qos_overrides."))
            raise ConfigError(f"bag_player: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(known)}")
        self._acks: dict[int, set[str]] = {}
        self._check_confirm_topics()
        # lossless: the output names of the confirm topics the bag has; confirmed ones drop out
        self._unconfirmed: set[str] = {self.options.output_topic(t) for t in self._confirm_topics}
        self._confirm_latest: dict[str, Any] = {}  # bag topic -> its latest published message
        self.result = PlaybackResult()  # the current (or last) play() call's counts
        from changing_slam_ros.nodes.diagnostics import NodeDiagnostics

        self.diagnostics = NodeDiagnostics(self, p["diagnostics_period_s"])
        self.diagnostics.set_source(lambda: {"published": self.result.published, "ack_timeouts": self.result.ack_timeouts,
                                             "dds_ack_timeouts": self.result.dds_ack_timeouts,
                                             "completed": self.result.completed})  # fmt: skip
        if self.lossless and ((self._ack_count > 0 and self._ack_topics) or self._unconfirmed):
            self.create_subscription(Header, p["ack_topic"], self._on_ack, QoSProfile(depth=1000))
        self.get_logger().info(
            f"bag_player: {self.bag.path} ({self.bag.kind.value}), {len(self.bag_publishers)} topics, "
            f"{self.bag.message_count} messages, {(self.bag.end_ns - self.bag.start_ns) / NS_PER_S:.2f} s, "
            f"rate {self.options.rate}, offset {self.options.start_offset_s} s"
            + (f", loop ({self.options.loop_passes or 'endless'} passes)" if self.options.loop else "")
            + (f", resuming pass {self.options.first_pass + 1} at {self.options.resume_at_s:.2f} s"
               if self.options.first_pass or self.options.resume_at_s else "")
            + (", lossless" if self.lossless else "")
        )

    # -- set-up ------------------------------------------------------------------------------
    def _declare_parameters(self, bag_path: str | None) -> dict[str, Any]:
        specs = [(name, bag_path or "", text) if name == "bag" else (name, default, text)
                 for name, default, text in BAG_PLAYER_PARAMETERS]
        values = declare_parameters(self, specs)
        for name in ("clock_hz", "progress_period_s", "confirm_resend_s"):
            if not values[name] > 0:
                raise ConfigError(f"bag_player: {name} must be > 0, got {values[name]}")
        return values

    def _check_confirm_topics(self) -> None:
        """A confirm topic the bag does not play (a bag without camera_info, say) has nothing to confirm."""
        unknown = [t for t in self._confirm_topics if t not in self.bag_publishers]
        if unknown:
            self.get_logger().warning(f"bag_player: confirm_topics {', '.join(unknown)} are not played topics "
                                      f"(played: {', '.join(sorted(self.bag_publishers))}); nothing to confirm there")
            self._confirm_topics = [t for t in self._confirm_topics if t in self.bag_publishers]

    def _make_publishers(self, depth: int) -> dict[str, Any]:
        """One publisher per bag topic with a known Python type; unknown types are skipped with a warning."""
        pubs: dict[str, Any] = {}
        wanted = set(self.options.topics)
        for topic, conn in sorted(self.bag.topics.items()):
            if wanted and topic not in wanted:
                continue
            try:
                cls = message_class(conn.msgtype)
            except (ImportError, ValueError) as err:
                self.get_logger().warning(f"bag_player: skipping {topic}: no Python type ({err})")
                continue
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_ALL if self.lossless else HistoryPolicy.KEEP_LAST,
                depth=max(1, depth),
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL if conn.latched else DurabilityPolicy.VOLATILE,
            )
            pubs[topic] = self.create_publisher(
                cls,
                self.options.output_topic(topic),
                qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            )
        missing = wanted - set(self.bag.topics)
        if missing:
            raise BagError(
                f"{self.bag.path}: no topic {', '.join(sorted(missing))}; the bag has {self.bag.describe_topics()}"
            )
        if not pubs:
            raise BagError(f"{self.bag.path}: nothing to publish; the bag has {self.bag.describe_topics()}")
        return pubs

    def destroy_node(self) -> None:
        self.bag.close()
        super().destroy_node()

    # -- playback ----------------------------------------------------------------------------
    def play(self, executor: Executor) -> PlaybackResult:
        """Publish the bag on schedule, spinning `executor` while waiting; returns at the end of the bag.

        Lossless: subscribers first (`_wait_for_subscribers`); publishers are reliable KEEP_ALL and, with
        `dds_ack_wait`, each message waits for every matched reliable subscription's DDS-level ack
        (`Publisher.wait_for_all_acked`); a message on an `ack_topics` topic waits for the previous one's
        processing acks (`_wait_processed`: one frame in flight; the messages in between still go out, so a node
        pairing a colour frame with the depth recorded after it can finish the frame; the last frame's ack is
        awaited at the end); unconfirmed `confirm_topics` are re-sent first (`_wait_confirmed`). Time spent
        waiting does not count against the schedule: playback resumes at the recorded spacing.
        """
        result = self.result = PlaybackResult()
        t_start = time.monotonic()
        c_start = time.process_time()
        if self._wait_subscribers and not self._wait_for_subscribers(executor):
            result.wall_s = time.monotonic() - t_start
            result.error = "no subscribers"
            return result
        start_bag_ns = first_bag_ns(self.bag, self.options)
        span_ns = self.bag.end_ns - start_bag_ns
        clock = PlaybackClock(self.options.rate, resume_bag_ns(self.bag, self.options), _now_ns())
        progress = PlaybackProgress(self._pass_message_count(), span_ns, self._progress_period_ns)
        current_pass = self.options.first_pass
        pending: Any = None  # lossless: last message on an ack topic, not yet acknowledged
        for item in plan(self.bag, self.options):
            if not self.context.ok():
                break
            pub = self.bag_publishers.get(item.msg.topic)
            if pub is None:
                continue
            if item.pass_index != current_pass:  # the clock runs on: the pass's stamps are shifted
                self.get_logger().info(f"bag_player: end of pass {current_pass + 1}, looping")
                current_pass = item.pass_index
                progress = PlaybackProgress(progress.total_messages, span_ns, self._progress_period_ns)
            if not self._sleep_until(clock, item.msg.log_stamp_ns, executor):
                break
            if self.lossless and self._confirm_latest and item.msg.topic in self._ack_topics:
                waited_from = _now_ns()
                self._wait_confirmed(executor, result)
                clock.pause(_now_ns() - waited_from)
            if pending is not None and item.msg.topic in self._ack_topics:
                # One frame in flight: the previous frame must be processed before the next one goes out.
                # (Waiting right after publishing would deadlock a node that pairs a colour frame with the
                # depth frame recorded after it.)
                waited_from = _now_ns()
                self._wait_processed(pending, executor, result)
                pending = None
                clock.pause(_now_ns() - waited_from)
            self._publish_clock(item.msg.log_stamp_ns)
            pub.publish(item.msg.cdr)
            clock.mark_published(item.msg.log_stamp_ns)
            result.published += 1
            result.per_topic[item.topic] = result.per_topic.get(item.topic, 0) + 1
            progress.record(item.topic)
            if self.lossless:
                if item.msg.topic in self._confirm_topics and self.options.output_topic(item.msg.topic) in self._unconfirmed:
                    self._confirm_latest[item.msg.topic] = item.msg
                waited_from = _now_ns()
                if self._dds_ack_wait and not pub.wait_for_all_acked(
                    Duration(nanoseconds=round(self._ack_timeout_s * NS_PER_S))
                ):
                    result.dds_ack_timeouts += 1
                clock.pause(_now_ns() - waited_from)
                if self._ack_count > 0 and item.msg.topic in self._ack_topics:
                    pending = item.msg
            if progress.due(_now_ns()):
                self.get_logger().info(
                    "bag_player: " + progress.line(current_pass, item.msg.log_stamp_ns - item.shift_ns - start_bag_ns)
                )
        else:
            result.completed = True
            if pending is not None:
                self._wait_processed(pending, executor, result)
        result.passes = current_pass + 1 - self.options.first_pass
        result.wall_s = time.monotonic() - t_start
        result.cpu_s = time.process_time() - c_start
        self.get_logger().info(
            f"bag_player: {'finished' if result.completed else 'stopped'}: {result.published} messages "
            f"in {result.wall_s:.2f} s (CPU {result.cpu_s:.2f} s)"
            + (f", {result.ack_timeouts} ack timeouts" if self.lossless else "")
            + (f", {result.confirm_resends} re-sends until confirmed" if result.confirm_resends else "")
        )
        return result

    def _pass_message_count(self) -> int:
        return sum(self.bag.topics[t].msgcount for t in self.bag_publishers)

    def _sleep_until(self, clock: PlaybackClock, bag_ns: int, executor: Executor) -> bool:
        """Spin until the message is due, publishing /clock at `clock_hz` while something subscribes to it (else
        one wake-up per message: a spin costs ~0.5 ms of CPU); False if the context shut down."""
        last_clock_ns = 0
        while self.context.ok():
            now = _now_ns()
            remaining = clock.wait_ns(bag_ns, now)
            if remaining <= 0:
                return True
            ticking = self._clock_period_ns is not None and self._clock_pub.get_subscription_count() > 0
            if ticking and now - last_clock_ns >= self._clock_period_ns:
                self._publish_clock(clock.bag_now_ns(now))
                last_clock_ns = now
            step = min(remaining, self._clock_period_ns) if ticking else remaining
            executor.spin_once(timeout_sec=step / NS_PER_S)
        return False

    def _publish_clock(self, bag_ns: int) -> None:
        """/clock at `bag_ns`, when clock publishing is on and something subscribes (volatile: nobody misses it)."""
        if self._clock_period_ns is None or self._clock_pub.get_subscription_count() == 0:
            return
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(bag_ns, NS_PER_S)
        self._clock_pub.publish(msg)

    def _wait_for_subscribers(self, executor: Executor) -> bool:
        """Spin until every topic of `wait_for_topics` (default: the `ack_topics`, else all played topics) has its
        subscribers (`_subscribers_needed`), at most `wait_subscribers_timeout_s`; False (an error logged) then.
        A message published before its subscription matched is lost, and a frame without depth or intrinsics is
        skipped: hence also the topics only tracking reads, such as depth and camera_info."""
        topics = self._wait_topics or sorted(self._ack_topics & set(self.bag_publishers)) or list(self.bag_publishers)
        unknown = [t for t in topics if t not in self.bag_publishers]
        if unknown:
            raise ConfigError(f"bag_player: wait_for_topics {', '.join(unknown)} are not played topics")
        deadline = time.monotonic() + self._wait_subscribers_timeout_s
        logged = False
        while self.context.ok():
            missing = [
                self.options.output_topic(t)
                for t in topics
                if self.bag_publishers[t].get_subscription_count() < self._subscribers_needed(t)
            ]
            if not missing:
                return True
            if time.monotonic() > deadline:
                self.get_logger().error(
                    f"bag_player: lossless: no subscriber on {', '.join(missing)} after "
                    f"{self._wait_subscribers_timeout_s} s; not playing"
                )
                return False
            if not logged:
                self.get_logger().info(f"bag_player: lossless: waiting for subscribers on {', '.join(missing)}")
                logged = True
            executor.spin_once(timeout_sec=0.05)
        return False

    def _subscribers_needed(self, topic: str) -> int:
        """`min_subscribers` on an ack topic (or every topic when none is set), one on the others."""
        return self._min_subscribers if topic in self._ack_topics or not self._ack_topics else 1

    def _wait_processed(self, msg: Any, executor: Executor, result: PlaybackResult) -> None:
        """Spin until `ack_count` nodes acknowledged `msg`'s stamp on `ack_topic`, at most `ack_timeout_s`."""
        stamp = msg.header_stamp_ns if msg.header_stamp_ns is not None else msg.log_stamp_ns
        deadline = time.monotonic() + self._ack_timeout_s
        while self.context.ok() and len(self._acks.get(stamp, ())) < self._ack_count:
            left_s = deadline - time.monotonic()
            if left_s < 0:
                result.ack_timeouts += 1
                self.get_logger().warning(
                    f"bag_player: lossless: no processing ack for {msg.topic} at {stamp / NS_PER_S:.6f} "
                    f"after {self._ack_timeout_s} s ({len(self._acks.get(stamp, ()))}/{self._ack_count})",
                    throttle_duration_sec=5.0,
                )
                break
            executor.spin_once(timeout_sec=min(left_s, 1.0))  # an ack wakes it at once: no need to poll
        self._acks.pop(stamp, None)

    def _wait_confirmed(self, executor: Executor, result: PlaybackResult) -> None:
        """Spin until every published confirm topic is confirmed, re-sending each one's latest message every
        `confirm_resend_s`; at most `ack_timeout_s` (then a warning, counted, and nothing more is waited for)."""
        deadline = time.monotonic() + self._ack_timeout_s
        next_resend = time.monotonic() + self._confirm_resend_s
        while self.context.ok():
            waiting = [t for t in self._confirm_latest if self.options.output_topic(t) in self._unconfirmed]
            if not waiting:
                break
            now = time.monotonic()
            if now > deadline:
                result.confirm_timeouts += 1
                self.get_logger().warning(
                    f"bag_player: lossless: no subscriber confirmed {', '.join(map(self.options.output_topic, waiting))} "
                    f"after {self._ack_timeout_s} s ({result.confirm_resends} re-sends); going on without"
                )
                self._unconfirmed.clear()
                break
            if now >= next_resend:
                for topic in waiting:
                    self.bag_publishers[topic].publish(self._confirm_latest[topic].cdr)
                    result.confirm_resends += 1
                next_resend = now + self._confirm_resend_s
            executor.spin_once(timeout_sec=max(0.001, min(next_resend, deadline) - now))
        self._confirm_latest.clear()

    def _on_ack(self, msg: Header) -> None:
        """A frame's ack names the node in `frame_id`; a topic's confirmation names the topic (leading '/'), and
        is never counted as a frame's ack (tracking confirms every camera_info it accepts)."""
        if msg.frame_id.startswith("/"):  # a topic's confirmation (a frame's ack names a node), confirmed or not
            self._unconfirmed.discard(msg.frame_id)
            return
        stamp = msg.stamp.sec * NS_PER_S + msg.stamp.nanosec
        self._acks.setdefault(stamp, set()).add(msg.frame_id)
        while len(self._acks) > 1000:  # acks for stamps never waited for (another publisher, a late ack)
            del self._acks[next(iter(self._acks))]


def _now_ns() -> int:
    return time.monotonic_ns()


def _play(node: Node, executor: Any) -> int:
    assert isinstance(node, BagPlayerNode)
    result = node.play(executor)
    return 1 if result.error else 0


NODE_HELP = NodeHelp("bag_player", first_line(__doc__), BAG_PLAYER_PARAMETERS, positional="[BAG]")


def main(args: Sequence[str] | None = None) -> int:
    def make(argv: list[str]) -> BagPlayerNode:
        if len(argv) > 1:
            raise ConfigError(f"bag_player: expected at most one bag argument, got {' '.join(argv)}")
        return BagPlayerNode(bag_path=argv[0] if argv else None)

    return run_node(make, args, body=_play, node_help=NODE_HELP)


if __name__ == "__main__":
    raise SystemExit(main())
