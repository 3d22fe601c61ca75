"""`loop_closing`: keyframes + map updates -> loop corrections (place recognition, verification, pose graph).

    python -m changing_slam_ros.nodes.loop_closing_node --ros-args -p config:=tum_fr1

Keeps a replica of the map fed by tracking's keyframe packets and local_mapping's MapUpdates
(`nodes/split_backend.py`, `LoopSide`). For each mapped keyframe, in the order local_mapping mapped them, it
updates the keyframe database and runs `core.slam.loop_closing.SlamMapLoopClosing` on it, and answers every
keyframe with a LoopCorrection (`closed: false`, or the correction and the delta it made to the replica);
local_mapping applies it to the map. A LoadMap on local_mapping restarts the replica from the loaded file
(`nodes/map_load.py`). Topics and parameters: docs/nodes.md#loop_closing.

After a restart the replica comes back from tracking's (`nodes/map_resync.py`). The keyframe local_mapping
mapped last may be in it without a verdict: its update went out before this process subscribed, or the
process it went to died deciding it. Answering it "no loop" unchecked would break the lossless order (a loop
there would be missed), so the node instead announces on the latched `~/ready` that its map is in place, and
local_mapping sends the update of the keyframe it still awaits a verdict on again, on
/local_mapping/verdict_requests (`LocalMappingNode.on_loop_closing_ready`). Such a request is decided as its
update would have been: on the restored keyframe (`LoopSide.decide_restored`: the restore indexed it as its
update would have), or, when the snapshot predates the update, by applying the update once the keyframe's
packet is in. A keyframe is answered once per process: requests for one answered already (local_mapping repeats
them until the verdict lands) are dropped, and requests wait until the ordinary updates queued before them
are processed, so the replica's changes keep local_mapping's order.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import Header

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import LoopCorrection as LoopCorrectionMsg
from changing_slam_msgs.msg import MapUpdate, ObjectStateArray
from changing_slam_ros.core.replication.map_replication import MapUpdate as MapUpdateData
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.diagnostics import NodeDiagnostics, summarise_ms
from changing_slam_ros.nodes.map_load import LoadEpochs, LoadMarker, loop_marker, marker_of
from changing_slam_ros.nodes.node_help import NodeHelp, ParamSpec, first_line
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.qos_profiles import LATCHED
from changing_slam_ros.nodes.replication_conversions import loop_result_to_msg, packet_from_msg, update_from_msg

KEYFRAME_QOS = QoSProfile(depth=100)


LOOP_CLOSING_PARAMETERS: tuple[ParamSpec, ...] = (
    ("config", "tum_fr1", "config name or YAML path (loop section: verification, pose graph)"),
    ("map_frame", "map", "frame of the corrected poses"),
    ("diagnostics_period_s", 5.0, "seconds between /diagnostics reports (0 = off)"),
    ("resync", True, "at start, ask tracking for its map (a node restarted beside a running tracking); false: "
                     "start empty (started together with tracking, as `changing-slam graph` does at first)"),
    ("resync_timeout_s", 20.0, "at start, how long to wait for tracking's map snapshot (a restart)"),
    ("map_file", "", "multi-session: start from this map file of `changing-slam run` (DIR/map.npz; "
                     "tracking and local_mapping load the same file; a node restarted in a running graph is started "
                     "without it and gets the current map from tracking)"),
    ("objects", "config", "the map owner's object layer (config, on, off): with map_file, the saved "
                          "objects' point flags are set here as local_mapping sets them"),
)  # fmt: skip


class LoopClosingNode(Node):
    def __init__(self, keyframe_qos: QoSProfile = KEYFRAME_QOS, **node_kwargs: Any) -> None:
        super().__init__("loop_closing", **node_kwargs)
        self.params = p = declare_parameters(self, LOOP_CLOSING_PARAMETERS)
        from changing_slam_ros.nodes.slam_backend import load_backend_config
        from changing_slam_ros.nodes.split_backend import LoopSide, object_layer_for

        self.cfg = cfg = load_backend_config(p["config"])
        self.side = LoopSide.build(cfg)
        if p["map_file"] and self.side is not None:
            from changing_slam_ros.io.map_file import load_map

            self.side.start_from_map(load_map(p["map_file"]), object_layer_for(cfg, p["objects"]))
            self.get_logger().info(f"loop_closing: {self.side.atlas.n_keyframes} keyframes loaded from {p['map_file']}")
        self.epochs = LoadEpochs.of("keyframes", "updates")  # local_mapping's ~/load_map (see nodes/map_load.py)
        self.loads = 0
        self.keyframes_in = 0
        self.updates_in = 0
        self.rejected = 0
        self.loops = 0
        self.merges = 0  # map merges found (Atlas); local_mapping applies them
        self.process_ms: list[float] = []
        self.updates: deque[tuple[MapUpdateData, Any]] = deque()  # waiting for their keyframe packet
        self.answered: set[int] = set()  # keyframes this process gave a verdict on (see the module doc)
        self.asked: dict[int, tuple[MapUpdateData, Any]] = {}  # local_mapping's verdict requests, not answered yet
        self.requests_in = 0
        self.requests_answered = 0
        self.create_subscription(KeyframeMsg, "/tracking/keyframes", self.on_keyframe, keyframe_qos)
        self.create_subscription(MapUpdate, "/local_mapping/map_updates", self.on_map_update, keyframe_qos)
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)
        self.create_subscription(MapUpdate, "/local_mapping/verdict_requests", self.on_verdict_request, keyframe_qos)
        self.correction_pub = self.create_publisher(LoopCorrectionMsg, "~/loop_corrections", keyframe_qos)
        self.ready_pub = self.create_publisher(Header, "~/ready", LATCHED)
        self._started_ns = time.time_ns()  # names this process in the announcement
        from changing_slam_ros.nodes.map_resync import ResyncClient

        # not with nothing to map, or when the map comes from the file (see map_file)
        ask = p["resync"] and self.side is not None and not p["map_file"]
        self.resync = ResyncClient(self, self._restore, give_up_s=p["resync_timeout_s"], on_ready=self._announce,
                                   ask=ask)  # fmt: skip
        self.diagnostics = NodeDiagnostics(self, p["diagnostics_period_s"])
        self.diagnostics.set_source(self.stats)
        state = "on" if self.side is not None else "OFF (the config's loop.enabled is false): every keyframe answered 'no loop'"
        self.get_logger().info(f"loop_closing: started (loop closing {state})")

    def on_keyframe(self, msg: KeyframeMsg) -> None:
        marker = marker_of(msg, msg.id)
        if marker is not None:
            self._on_marker("keyframes", marker)
            return
        if not self.epochs.current("keyframes"):
            return  # a packet of the map before the load
        try:
            packet = packet_from_msg(msg, "/tracking/keyframes")
        except (SlamError, ValueError) as err:
            self.rejected += 1
            self.get_logger().warning(f"loop_closing: keyframe rejected: {err}", throttle_duration_sec=5.0)
            return
        if self.side is not None:
            try:
                self.side.on_keyframe(packet)
            except SlamError as err:
                self.rejected += 1
                self.get_logger().warning(f"loop_closing: keyframe rejected: {err}", throttle_duration_sec=5.0)
                return
        self.keyframes_in += 1
        self._drain()

    def on_map_update(self, msg: MapUpdate) -> None:
        marker = marker_of(msg, msg.keyframe_id)
        if marker is not None:
            self._on_marker("updates", marker)
            return
        if not self.epochs.current("updates"):
            return  # the old owner's change of the map before the load
        try:
            update = update_from_msg(msg, "/local_mapping/map_updates")
        except (SlamError, ValueError) as err:
            self.rejected += 1
            self.get_logger().warning(f"loop_closing: map update rejected: {err}", throttle_duration_sec=5.0)
            return
        self.updates_in += 1
        self.updates.append((update, msg.header.stamp))
        self._drain()

    def on_verdict_request(self, msg: MapUpdate) -> None:
        """local_mapping's update of a keyframe it awaits a verdict on, sent again after this node announced
        itself (see the module doc); answered in `_drain` unless answered already."""
        try:
            update = update_from_msg(msg, "/local_mapping/verdict_requests")
        except (SlamError, ValueError) as err:
            self.rejected += 1
            self.get_logger().warning(f"loop_closing: verdict request rejected: {err}", throttle_duration_sec=5.0)
            return
        k = update.keyframe_id
        if k < 0 or update.merge is not None or k in self.answered or k in self.asked:
            return  # repeated until the verdict lands: one answer per keyframe
        self.requests_in += 1
        self.asked[k] = (update, msg.header.stamp)
        self.get_logger().info(f"loop_closing: local_mapping awaits the verdict on keyframe {k}")
        self._drain()

    def _announce(self) -> None:
        """The map is in place (restored, started empty or loaded): local_mapping may ask for verdicts now."""
        from changing_slam_ros.nodes.conversions import make_header

        self.ready_pub.publish(make_header(self._started_ns, self.get_name()))

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # active flags arrive with the map updates (the object layer runs in local_mapping)

    def _on_marker(self, stream: str, marker: LoadMarker) -> None:
        """A load announced on `stream`: the first announcement of a newer load resets the replica to its file."""
        if not self.epochs.on_marker(stream, marker):
            return
        from changing_slam_ros.io.map_file import load_map
        from changing_slam_ros.nodes.split_backend import LoopSide, object_layer_for

        self.epochs.adopt(marker)
        self.updates.clear()
        self.asked.clear()
        self.answered.clear()
        if not self.resync.ready:
            self.resync.skip()
        side = LoopSide.build(self.cfg)
        if side is not None:
            try:
                side.start_from_map(load_map(marker.path), object_layer_for(self.cfg, self.params["objects"]))
            except (SlamError, OSError, ValueError) as err:  # local_mapping loaded it: the file changed since
                self.get_logger().error(f"loop_closing: map {marker.path} not loaded ({err}); starting empty")
                side = LoopSide.build(self.cfg)
        self.side = side
        self.loads += 1
        self.correction_pub.publish(loop_marker(marker))
        n = 0 if side is None else side.atlas.n_keyframes
        self.get_logger().info(f"loop_closing: {n} keyframes loaded from {marker.path} (LoadMap)")

    def _restore(self, keyframes: list[Any], delta: Any) -> None:
        if self.side is not None:
            self.side.restore(keyframes, delta)
        self._drain()

    def _drain(self) -> None:
        """Apply updates in order; one for a keyframe whose packet has not arrived yet waits for it. Verdict
        requests are answered once no update waits before them."""
        while self.updates and self.resync.ready:
            update, stamp = self.updates[0]
            if self._packet_missing(update.keyframe_id):
                return
            self.updates.popleft()
            self._process(update, stamp)
        if self.updates or not self.resync.ready:
            return
        for k in sorted(self.asked):
            if k in self.answered:  # its ordinary update came meanwhile
                del self.asked[k]
            elif not self._packet_missing(k):
                self._answer_request(*self.asked.pop(k))

    def _packet_missing(self, kf_id: int) -> bool:
        """The update of `kf_id` needs its keyframe packet first: neither pending nor restored."""
        return self.side is not None and kf_id >= 0 and kf_id not in self.side.pending and not self.side.knows(kf_id)

    def _answer_request(self, update: MapUpdateData, stamp: Any) -> None:
        """A verdict request: the restored keyframe decided in place, or its missed update applied and decided."""
        from changing_slam_ros.core.replication.map_replication import LoopResult

        k = update.keyframe_id
        t0 = time.monotonic()
        try:
            if self.side is None:
                result = LoopResult(k, False)
            elif self.side.knows(k):
                result = self.side.decide_restored(k)
            else:
                result = self.side.on_update(update)
        except SlamError as err:
            self.rejected += 1
            self.get_logger().warning(f"loop_closing: verdict request for keyframe {k} failed: {err}")
            return
        if result is None:
            return
        self.requests_answered += 1
        self.get_logger().info(f"loop_closing: keyframe {k} decided on local_mapping's request")
        self._publish(result, stamp, update.delta.map_id, t0)

    def _process(self, update: MapUpdateData, stamp: Any) -> None:
        from changing_slam_ros.core.replication.map_replication import LoopResult

        if update.keyframe_id in self.answered:
            return  # applied and answered on local_mapping's request already: again, it would undo a loop closed then
        t0 = time.monotonic()
        if self.side is None:
            result = LoopResult(update.keyframe_id, False) if update.keyframe_id >= 0 else None
        else:
            try:
                result = self.side.on_update(update)
            except SlamError as err:
                self.rejected += 1
                self.get_logger().warning(f"loop_closing: map update not applied: {err}", throttle_duration_sec=5.0)
                return
        if result is not None:
            self._publish(result, stamp, update.delta.map_id, t0)

    def _publish(self, result: Any, stamp: Any, map_id: int, t0: float) -> None:
        from changing_slam_ros.nodes.conversions import stamp_to_ns

        self.answered.add(result.query_kf_id)
        self.process_ms.append((time.monotonic() - t0) * 1e3)
        self.loops += int(result.closed)
        if result.closed:
            self.get_logger().info(f"loop_closing: loop closed at keyframe {result.query_kf_id}")
        if result.merge is not None:
            self.merges += 1
            self.get_logger().info(f"loop_closing: keyframe {result.query_kf_id} of map {result.merge.query_map_id} "
                                   f"sees keyframe {result.merge.match_kf_id} of map {result.merge.match_map_id}: merge")
        self.correction_pub.publish(loop_result_to_msg(result, stamp_to_ns(stamp), self.params["map_frame"], map_id))

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {"keyframes_received": self.keyframes_in, "updates_received": self.updates_in,
                               "updates_waiting": len(self.updates),
                               "verdict_requests": self.requests_in, "verdict_requests_answered": self.requests_answered,
                               "rejected": self.rejected, "loops_closed": self.loops, "merges_found": self.merges,
                               "restored_keyframes": self.resync.restored_keyframes, "map_loads": self.loads,
                               "dropped_before_load": self.epochs.dropped}  # fmt: skip
        if self.side is not None:
            out["keyframes_moved_by_merges"] = self.side.n_moved_keyframes + self.side.log.n_moved
        out.update(summarise_ms(self.process_ms, "keyframe"))
        return out


NODE_HELP = NodeHelp("loop_closing", first_line(__doc__), LOOP_CLOSING_PARAMETERS)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: LoopClosingNode(), args, node_help=NODE_HELP)


if __name__ == "__main__":
    raise SystemExit(main())
