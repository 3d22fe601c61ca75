"""Map resync after a restart: a restarted `local_mapping` or `loop_closing` rebuilds its map from tracking's.

    client = ResyncClient(node, on_restore=lambda kfs, delta: owner.restore(kfs, delta))   # in the restarted node
    ResyncServer(node, snapshot=tracking_side.snapshot)                                     # in tracking

The client asks on /map_resync/request (std_msgs/Header, frame_id = its node name) every `period_s` until
tracking answers: every keyframe of its replica on /tracking/keyframe_snapshot (Keyframe: features and pose)
and then one MapUpdate per map on /tracking/map_snapshot with the map in full (`core.map_replication.full_delta`,
header.frame_id = the asking node, keyframe_id -1, loop_query_keyframe_id = the number of maps in the snapshot;
keyframe_id -2: tracking has no map yet). Topics are different streams, so the client keeps the keyframes until all
that a snapshot names are in, then calls `on_restore`. A node that starts with the graph asks too; tracking
answers with nothing (no keyframes yet) and the node goes on. Until answered (or `give_up_s`), `ready` is False
so the node holds back keyframes that name points of the map it does not have yet.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import Header

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import MapUpdate
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.replication.map_replication import MapDelta
from changing_slam_ros.errors import SlamError

REQUEST_TOPIC = "/map_resync/request"
KEYFRAMES_TOPIC = "/tracking/keyframe_snapshot"
MAP_TOPIC = "/tracking/map_snapshot"
SNAPSHOT_QOS = QoSProfile(depth=1000)  # reliable: a snapshot is every keyframe at once


class ResyncClient:
    def __init__(self, node: Node, on_restore: Callable[[list[Keyframe], MapDelta], None], period_s: float = 1.0,
                 give_up_s: float = 20.0, on_ready: Callable[[], None] | None = None, ask: bool = True) -> None:  # fmt: skip
        """`ask` False: the node has its map already or starts with tracking (nothing to restore), so it is ready
        at once and never asks: an answer racing tracking's first keyframe would restore that keyframe from tracking's
        replica instead of mapping it, and runs would differ by timing."""
        self.node = node
        self.on_restore = on_restore
        self.on_ready = on_ready  # called once, when `ready` turns True (restored, started empty or skipped)
        self.ready = False
        self.restored_keyframes = 0
        self.restored_maps = 0
        self._keyframes: dict[int, Keyframe] = {}
        self._maps: list[tuple[MapDelta, int]] = []  # (delta, n maps in the snapshot)
        self._give_up = time.monotonic() + give_up_s
        self._request_pub = node.create_publisher(Header, REQUEST_TOPIC, 10)
        node.create_subscription(KeyframeMsg, KEYFRAMES_TOPIC, self._on_keyframe, SNAPSHOT_QOS)
        node.create_subscription(MapUpdate, MAP_TOPIC, self._on_map, SNAPSHOT_QOS)
        self._timer = node.create_timer(period_s, self._ask, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if ask:
            self._ask()
        else:
            self._finish()

    def _ask(self) -> None:
        if self.ready:
            return
        if time.monotonic() > self._give_up:
            self.node.get_logger().warning(f"{self.node.get_name()}: no map snapshot from tracking; starting empty")
            self._finish()
            return
        self._request_pub.publish(Header(frame_id=self.node.get_name()))

    def skip(self) -> None:
        """The node has its map already (loaded from a file): no snapshot is asked for, keyframes flow at once."""
        self._finish()

    def _finish(self) -> None:
        if self.ready:
            return
        self.ready = True
        self._timer.cancel()
        self._keyframes.clear()
        if self.on_ready is not None:
            self.on_ready()

    def _on_keyframe(self, msg: KeyframeMsg) -> None:
        if self.ready:
            return
        from changing_slam_ros.nodes.conversions import keyframe_from_msg

        try:
            kf = keyframe_from_msg(msg, KEYFRAMES_TOPIC)
        except (SlamError, ValueError) as err:
            self.node.get_logger().warning(f"{self.node.get_name()}: snapshot keyframe rejected: {err}")
            return
        self._keyframes[kf.id] = kf
        self._try_restore()

    def _on_map(self, msg: MapUpdate) -> None:
        if self.ready or msg.header.frame_id != self.node.get_name():
            return
        from changing_slam_ros.nodes.replication_conversions import delta_from_msg

        if msg.keyframe_id == -2:  # tracking has no map yet: nothing to restore
            self.node.get_logger().info(f"{self.node.get_name()}: tracking has no map yet; starting empty")
            self._finish()
            return
        try:
            self._maps.append((delta_from_msg(msg.delta, MAP_TOPIC), int(msg.loop_query_keyframe_id)))
        except (SlamError, ValueError) as err:
            self.node.get_logger().warning(f"{self.node.get_name()}: map snapshot rejected: {err}")
            return
        self._try_restore()

    def _try_restore(self) -> None:
        if not self._maps or len(self._maps) < self._maps[0][1]:
            return
        if any(k not in self._keyframes for d, _ in self._maps for k in d.keyframes.ids.tolist()):
            return
        for delta, _ in sorted(self._maps, key=lambda x: x[0].map_id):
            kfs = [self._keyframes[k] for k in delta.keyframes.ids.tolist()]
            try:
                self.on_restore(kfs, delta)
            except SlamError as err:
                self.node.get_logger().error(f"{self.node.get_name()}: map {delta.map_id} not restored: {err}")
                continue
            self.restored_maps += 1
            self.restored_keyframes += len(kfs)
        self.node.get_logger().info(f"{self.node.get_name()}: map restored from tracking's replica "
                                    f"({self.restored_maps} maps, {self.restored_keyframes} keyframes)")  # fmt: skip
        self._finish()


class ResyncServer:
    """Tracking's side: answers requests with its replica (`snapshot()`: (keyframes, full delta) per map)."""

    def __init__(self, node: Node, snapshot: Callable[[], list[tuple[list[Keyframe], MapDelta]]],
                 frame_id: str, after: Callable[[str], None] | None = None) -> None:  # fmt: skip
        self.node = node
        self.snapshot = snapshot
        self.after = after  # called with the asker's name after each answer (tracking re-sends what is missing)
        self.frame_id = frame_id
        self.answered = 0
        self._kf_pub = node.create_publisher(KeyframeMsg, KEYFRAMES_TOPIC, SNAPSHOT_QOS)
        self._map_pub = node.create_publisher(MapUpdate, MAP_TOPIC, SNAPSHOT_QOS)
        node.create_subscription(Header, REQUEST_TOPIC, self._on_request, 10)

    def _on_request(self, msg: Header) -> None:
        from changing_slam_ros.core.replication.map_replication import MapUpdate as MapUpdateData
        from changing_slam_ros.nodes.conversions import keyframe_to_msg, make_header
        from changing_slam_ros.nodes.replication_conversions import update_to_msg

        maps = self.snapshot()
        self.answered += 1
        if not maps:
            self._map_pub.publish(MapUpdate(header=Header(frame_id=msg.frame_id), keyframe_id=-2))
            if self.after is not None:
                self.after(msg.frame_id)
            return
        for keyframes, _ in maps:
            for kf in keyframes:
                self._kf_pub.publish(keyframe_to_msg(kf, self.frame_id))
        for _, delta in maps:
            out = update_to_msg(MapUpdateData(-1, delta, loop_query_kf_id=len(maps)), 0, self.frame_id)
            out.header = make_header(0, msg.frame_id)  # addressed to the node that asked
            self._map_pub.publish(out)
        self.node.get_logger().info(f"tracking: map snapshot sent to {msg.frame_id} "
                                    f"({sum(len(k) for k, _ in maps)} keyframes)")  # fmt: skip
        if self.after is not None:
            self.after(msg.frame_id)
